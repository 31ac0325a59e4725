"""One cycle's work: a profile row played at its pace, or the module's own CPU work.

A module either plays its profile row (the operator's row for its node and CPU limit,
``burn.Burner``: the row's CPU for the row's time, the stand-in for a module whose profile is
known) or does its own work (``module --cpu-work MILLIS``: that many milliseconds of CPU a
cycle, single-threaded, as fast as its CPU limit lets it, so the kernel's CFS quota decides
how long a cycle takes, as it does for a real module nobody has profiled yet). The cycle loop
and the profiling run (``workload.profile``) ask this object for one cycle's work and never
branch on which it is.
"""

from __future__ import annotations

import random
import time

from .burn import Burner
from .spec import WorkloadSpec, sample_exec_seconds

__all__ = ["CpuWork", "RowWork", "Work", "describe", "work_for"]


class Work:
    """One cycle's work; ``run`` returns its wall time in seconds."""

    def run(self) -> float:
        raise NotImplementedError

    def close(self) -> None:
        """Release worker processes (if any)."""


class RowWork(Work):
    """The profile row at the module's CPU limit, its time drawn from the row's mean and std."""

    def __init__(self, spec: WorkloadSpec, rng: random.Random) -> None:
        self.row = spec.row  # raises ValueError without a row for this node
        self.factor = spec.work_factor
        self.rng = rng
        self.burner = Burner(self.row.cpu)  # forks its workers: before ROS starts

    def run(self) -> float:
        return self.burner.run(sample_exec_seconds(self.row, self.rng) * self.factor)

    def close(self) -> None:
        self.burner.close()


class CpuWork(Work):
    """``seconds`` of CPU a cycle, burnt at full speed on one core."""

    def __init__(self, seconds: float, factor: float = 1.0) -> None:
        if not seconds > 0:
            raise ValueError(f"cpu work must be positive, got {seconds}")
        self.seconds = seconds * factor

    def run(self) -> float:
        """Spin until this thread has used the work's CPU (the module's other threads, its
        middleware's, are not counted: they are not its work); returns the wall time."""
        # the wall clock is read first and last, so the wall interval holds the CPU interval
        # (the other order lost the time of one clock read: 4.9994 ms of wall for 5 ms of CPU)
        wall0 = time.monotonic()
        t0 = time.thread_time()
        x = 0
        while time.thread_time() - t0 < self.seconds:
            for _ in range(500):
                x += 1
        return time.monotonic() - wall0


def describe(spec: WorkloadSpec) -> str:
    """The module's work in words, for its first log line."""
    if spec.cpu_work_s is not None:
        return f"its own work: {spec.cpu_work_s * spec.work_factor * 1e3:g} ms of CPU a cycle"
    row = spec.row
    return f"work {row.mean_s * 1e3:g}±{row.std_s * 1e3:g} ms at {row.cpu:g} CPU" + (
        f" x{spec.work_factor:g}" if spec.work_factor != 1 else ""
    )


def work_for(spec: WorkloadSpec, rng: random.Random) -> Work:
    """The module's own work when it has one (``--cpu-work``), else its profile row's."""
    if spec.cpu_work_s is not None:
        return CpuWork(spec.cpu_work_s, spec.work_factor)
    return RowWork(spec, rng)
