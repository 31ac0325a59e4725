"""Measure a network's per-split profile on this machine: the SoftwareModule's ``dnn`` field.

For each split point: the head's and the tail's time per frame and the bytes that cross; the
whole network's time (full offload, ``a = 0``); the local variant's time on the robot
(``a = n+1``); the input and output bytes (roboec2-dnn-offloading, eq. 4's ``Data^0 ...
Data^{n+1}``; ``DNNSPLIT.md`` 3.2's proposed field). Times are medians of ``runs`` runs after
``warmup`` runs, single-threaded (:func:`.runner.session`), in milliseconds on the measuring
core. By default they are the thread's CPU time rather than wall time: onnxruntime with one
intra-op thread computes on the calling thread, and CPU time is the work on the core, nearly
the same on a busy machine as on a quiet one (fogfleet's own rule for its tests); ``wall``
counts preemption too.

Accuracy, the spotlight and the bounds (alpha, theta, gamma, rate) are declared by the user,
not measured: the weights are random (``DNNSPLIT.md`` 3.5).
"""

from __future__ import annotations

import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import onnxruntime as ort
import yaml

from .network import NetSpec, build_network, local_variant, split_point_names
from .runner import SplitRunner, Stage, sample_frame
from .split import split_all, tensor_bytes

__all__ = ["CLOCKS", "DnnProfile", "SplitTiming", "measure", "median_ms", "to_yaml"]

CLOCKS: dict[str, Callable[[], float]] = {"cpu": time.thread_time, "wall": time.perf_counter}
DECIMALS = 3


@dataclass(frozen=True)
class SplitTiming:
    """One split point's measurement."""

    name: str
    head_ms: float
    tail_ms: float
    tensor_bytes: int


@dataclass(frozen=True)
class DnnProfile:
    """A network's measured profile (what the ``dnn`` field declares that can be measured)."""

    input_bytes: int
    output_bytes: int
    full_ms: float
    split_points: tuple[SplitTiming, ...]
    local_name: str
    local_ms: float

    def to_field(self) -> dict[str, Any]:
        """The SoftwareModule's ``dnn`` field (camelCase), measured parts only."""
        return {
            "inputBytes": self.input_bytes,
            "outputBytes": self.output_bytes,
            "fullMillis": self.full_ms,
            "splitPoints": [
                {
                    "name": s.name,
                    "headMillis": s.head_ms,
                    "tailMillis": s.tail_ms,
                    "tensorBytes": s.tensor_bytes,
                }
                for s in self.split_points
            ],
            "localModel": {"name": self.local_name, "robotMillis": self.local_ms},
        }


def median_ms(
    call: Callable[[], object],
    runs: int,
    warmup: int,
    clock: Callable[[], float] = time.thread_time,
) -> float:
    """The median time of ``runs`` calls after ``warmup`` untimed ones, in milliseconds."""
    if runs < 1 or warmup < 0:
        raise ValueError(f"runs {runs} (at least 1), warm-up {warmup} (0 or more)")
    for _ in range(warmup):
        call()
    times = []
    for _ in range(runs):
        start = clock()
        call()
        times.append(clock() - start)
    return round(statistics.median(times) * 1e3, DECIMALS)


def measure(spec: NetSpec, runs: int = 25, warmup: int = 5, clock: str = "cpu") -> DnnProfile:
    """Build ``spec``'s network and its local variant, cut it at every split point and time
    every part on a random frame."""
    tick = CLOCKS[clock]
    model = build_network(spec)
    local_spec = local_variant(spec)
    frame = sample_frame(spec)

    def timed(stage: Stage, x: Any) -> float:
        return median_ms(lambda: stage(x), runs, warmup, tick)

    full_ms = timed(Stage.of(model), frame)
    local_ms = timed(Stage.of(build_network(local_spec)), frame)
    points = []
    for split in split_all(model, split_point_names(spec)):
        runner = SplitRunner.of(split)
        tensor = runner.head(frame)
        points.append(
            SplitTiming(
                split.name,
                timed(runner.head, frame),
                timed(runner.tail, tensor),
                split.tensor_bytes,
            )
        )
    return DnnProfile(
        input_bytes=tensor_bytes(model.graph.input[0]),
        output_bytes=tensor_bytes(model.graph.output[0]),
        full_ms=full_ms,
        split_points=tuple(points),
        local_name=local_spec.name,
        local_ms=local_ms,
    )


def to_yaml(profile: DnnProfile, spec: NetSpec, runs: int, warmup: int, clock: str) -> str:
    """``dnn:`` and the profile, each split point on one line, after comments that say where
    and how it was measured and what the user still declares."""
    body = yaml.safe_dump(
        {"dnn": profile.to_field()}, sort_keys=False, default_flow_style=None, width=100
    )
    return (
        f"# {spec.name}: {spec.input_size}x{spec.input_size} input, width {spec.width:g}, "
        f"bottleneck {spec.bottleneck}, seed {spec.seed}; local variant width "
        f"{local_variant(spec).width:g}\n"
        f"# onnxruntime {ort.__version__}, 1 thread, {clock} time, median of {runs} runs "
        f"after {warmup} warm-up, on {_processor()}\n"
        "# declare accuracy and localModel.accuracy (the weights are random: they have none)\n"
        "# and, if you want them, spotlight, maxLatencyMillis, minAccuracy and maxRobotMillis\n"
        + body
    )


def _processor() -> str:
    """This machine's CPU model, as /proc/cpuinfo names it (else the platform's word)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "an unknown CPU"
