"""A split module's profiling Job (issue 48 item 4; ``contract.dnn``'s Profiling paragraph):
time every part of the image's network on this node, from the image's model files.

What the developer's profiler (``profile.py``) measures on the network it builds, measured here
on the files the image ships, with onnxruntime alone (``sessions.Net``: the image has no onnx):
the whole network's time per frame (full offload, ``a = 0``), the local model's (``a = n+1``),
every split point's head and tail time and the bytes that cross, and the input and output
bytes (roboec2-dnn-offloading, eq. 4's per-action times and ``Data^0 ... Data^{n+1}``).

Each time is the median of ``frames`` calls after ``warmup`` untimed ones, on one random frame
(a tail on its head's real output), in milliseconds of the calling thread's CPU time by
default: onnxruntime with one intra-op thread computes on the caller, and CPU time is the work
on the core, nearly the same on a busy node as on a quiet one (``profile.py``'s default clock).
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fogfleet.contract.dnn import PROFILE_WARMUP, RESULT_KEY

from ..profile import MAX_MESSAGE_BYTES
from .layout import FULL_FILE, LOCAL_FILE, head_file, tail_file
from .sessions import Net

__all__ = ["measure_models", "run_dnn_profile"]

DECIMALS = 3  # milliseconds to the microsecond, as every profile line

Clock = Callable[[], float]


@dataclass(frozen=True)
class _Timer:
    """How every part is timed: ``frames`` timed calls after ``warmup`` untimed ones."""

    frames: int
    warmup: int
    clock: Clock

    def __post_init__(self) -> None:
        if self.frames < 1 or self.warmup < 0:
            raise ValueError(
                f"{self.frames} frames (at least 1), {self.warmup} warm-up frames (0 or more)"
            )

    def seconds(self, call: Callable[[], object]) -> list[float]:
        """Each timed call's time on the clock, in seconds."""
        for _ in range(self.warmup):
            call()
        times = []
        for _ in range(self.frames):
            start = self.clock()
            call()
            times.append(self.clock() - start)
        return times

    def median_ms(self, call: Callable[[], object]) -> float:
        return _millis(statistics.median(self.seconds(call)))


@dataclass(frozen=True)
class _Measured:
    """The ``RESULT_KEY`` payload, and the whole network's timed frames (the Job's mean)."""

    payload: dict[str, Any]
    full_seconds: list[float]


def _millis(seconds: float) -> float:
    return round(seconds * 1e3, DECIMALS)


def _sample_frame(net: Net, seed: int = 0) -> np.ndarray:
    """A synthetic camera frame in ``net``'s input shape (uint8), as ``RobotNets.capture``."""
    rng = np.random.default_rng(seed)
    frame: np.ndarray = rng.integers(0, 256, net.input_shape, dtype=np.uint8)
    return frame


def _split_point(
    name: str, head: Net, tail: Net, frame: np.ndarray, timer: _Timer
) -> dict[str, Any]:
    """One split point's times and the bytes its head sends across."""
    tensor = head(frame)
    received = tail.from_bytes(tensor.tobytes())  # as the tail gets it (ValueError: no pair)
    return {
        "name": name,
        "headMillis": timer.median_ms(lambda: head(frame)),
        "tailMillis": timer.median_ms(lambda: tail(received)),
        "tensorBytes": tensor.nbytes,
    }


def _measure(folder: Path, splits: Sequence[str], timer: _Timer) -> _Measured:
    """Load every part first (a missing file fails before any timing), then time each."""
    full = Net.load(folder / FULL_FILE)
    local = Net.load(folder / LOCAL_FILE)
    halves = [
        (name, Net.load(folder / head_file(name)), Net.load(folder / tail_file(name)))
        for name in splits
    ]
    frame = _sample_frame(local)
    full_seconds = timer.seconds(lambda: full(frame))
    payload = {
        "inputBytes": frame.nbytes,
        "outputBytes": full(frame).nbytes,
        "fullMillis": _millis(statistics.median(full_seconds)),
        "localMillis": timer.median_ms(lambda: local(frame)),
        "splitPoints": [_split_point(n, h, t, frame, timer) for n, h, t in halves],
    }
    return _Measured(payload, full_seconds)


def measure_models(
    folder: Path,
    splits: Sequence[str],
    frames: int,
    warmup: int = PROFILE_WARMUP,
    clock: Clock = time.thread_time,
) -> dict[str, Any]:
    """The ``RESULT_KEY`` payload of the models in ``folder`` for split points ``splits`` (in
    order). FileNotFoundError names a missing model file; ValueError, a head whose tensor its
    tail does not take, or a frame count below 1."""
    return _measure(folder, splits, _Timer(frames, warmup, clock)).payload


def run_dnn_profile(
    folder: Path, splits: Sequence[str], frames: int, output: str
) -> dict[str, Any]:
    """Measure (``measure_models``), write the result as one JSON line to ``output`` (the
    termination message), print it and return it: ``meanMillis`` and ``stdMillis`` are the
    whole network's timed frames', ``cpuSeconds`` and ``wallSeconds`` the whole run's (the
    models' loading included). ValueError when the line would not fit a termination message
    (too many split points); OSError when ``output`` cannot be written."""
    cpu0, wall0 = time.process_time(), time.monotonic()
    measured = _measure(folder, splits, _Timer(frames, PROFILE_WARMUP, time.thread_time))
    full_ms = [t * 1e3 for t in measured.full_seconds]
    result = {
        "cycles": frames,
        "meanMillis": round(statistics.mean(full_ms), DECIMALS),
        "stdMillis": round(statistics.stdev(full_ms), DECIMALS) if frames > 1 else 0.0,
        "cpuSeconds": round(time.process_time() - cpu0, DECIMALS),
        "wallSeconds": round(time.monotonic() - wall0, DECIMALS),
        RESULT_KEY: measured.payload,
    }
    line = json.dumps(result, separators=(",", ":"))
    size = len(line.encode())
    if size > MAX_MESSAGE_BYTES:
        raise ValueError(
            f"the profile of {len(splits)} split points is a {size}-byte line, over the "
            f"{MAX_MESSAGE_BYTES} bytes (4 KiB) of a termination message: too many split "
            "points (or too long names) for one message"
        )
    try:
        Path(output).write_text(line + "\n")
    except OSError as exc:
        raise OSError(f"cannot write the profile to {output}: {exc}") from exc
    print(line, flush=True)
    return result
