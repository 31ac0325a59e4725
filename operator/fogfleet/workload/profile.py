"""The profiling contract (issue 10): ``FOGFLEET_PROFILE_CYCLES=N`` runs N cycles of the
module's work alone and writes what they took to the pod's termination message.

The operator's profiling Job (``render.profiling``) runs the module's own container at one CPU
limit on one hardware type. Without ROS (a benchmark of the module's work, as replaying a
recording would be), the module runs its work every cycle time, or at once when the previous
cycle ended later (as the module itself does), and reports one JSON line of at most 4 KiB
(Kubernetes' limit for a termination message): the cycles' mean, sample std, nearest-rank
p95 and max execution time, and the CPU and wall time the run used. No numpy: the workload
image carries none.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fogfleet.contract.env import ENV_PROFILE_CYCLES, ENV_PROFILE_OUTPUT

from .spec import WorkloadSpec
from .work import Work

__all__ = [
    "DEFAULT_OUTPUT",
    "ENV_PROFILE_CYCLES",
    "ENV_PROFILE_OUTPUT",
    "MAX_MESSAGE_BYTES",
    "profile_cycles",
    "run_profile",
    "summarise",
]

DEFAULT_OUTPUT = "/dev/termination-log"
MAX_MESSAGE_BYTES = 4096


def profile_cycles(env: Mapping[str, str]) -> int | None:
    """N from ``FOGFLEET_PROFILE_CYCLES`` (None: not a profiling run)."""
    text = env.get(ENV_PROFILE_CYCLES)
    if text is None or text == "":
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{ENV_PROFILE_CYCLES}={text!r}: a whole number of cycles, at least 1")
    return value


def summarise(
    times_s: Sequence[float], cpu_seconds: float, wall_seconds: float, spec: WorkloadSpec
) -> dict[str, Any]:
    """The result line's fields (times in milliseconds, rounded to 3 decimals)."""
    if not times_s:
        raise ValueError("no cycle to summarise")
    ms = sorted(t * 1e3 for t in times_s)
    n = len(ms)
    mean = sum(ms) / n
    std = math.sqrt(sum((t - mean) ** 2 for t in ms) / (n - 1)) if n > 1 else 0.0
    p95 = ms[max(0, math.ceil(0.95 * n) - 1)]  # nearest rank
    return {
        "module": spec.module,
        "hardwareType": spec.hardware_type,
        "node": spec.node,
        "cpu": spec.cpu_label,
        "cycles": n,
        "meanMillis": round(mean, 3),
        "stdMillis": round(std, 3),
        "p95Millis": round(p95, 3),
        "maxMillis": round(ms[-1], 3),
        "cpuSeconds": round(cpu_seconds, 3),
        "wallSeconds": round(wall_seconds, 3),
    }


def run_profile(spec: WorkloadSpec, work: Work, cycles: int, output: str) -> dict[str, Any]:
    """Run ``cycles`` cycles of ``work`` at the module's pace; write and return the summary.
    Raises OSError when ``output`` cannot be written."""
    times: list[float] = []
    cpu0, wall0 = time.process_time(), time.monotonic()
    start = end = wall0
    for k in range(cycles):
        if k:  # the next cycle starts a cycle time after the last one, or when it ended
            start = max(start + spec.cycle_s, end)
            time.sleep(max(0.0, start - time.monotonic()))
        times.append(work.run())
        end = time.monotonic()
    result = summarise(times, time.process_time() - cpu0, end - wall0, spec)
    line = json.dumps(result, separators=(",", ":"))
    if len(line.encode()) > MAX_MESSAGE_BYTES:  # long names: keep the figures
        result = {k: v for k, v in result.items() if k not in {"module", "node"}}
        line = json.dumps(result, separators=(",", ":"))
    Path(output).write_text(line + "\n")
    print(line, flush=True)
    return result
