"""CPU seconds each part of the bed spends over a benchmark phase: where a rollout's time goes
on a machine whose cores the control plane, the fake nodes, the operator and the benchmark
itself all share.

Read from ``/proc/<pid>/stat`` (user + system time, the process's threads included) of the
harness's recorded processes (``e2e.bed.processes``: the exact pid and start time) and
of any other pid the caller names, at the phase's start and end; ``machine`` is every core's
busy time from ``/proc/stat`` (so ``machine`` / (cores x wall) is how saturated it was).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from e2e.bed.processes import _alive

__all__ = ["CONTROL_PLANE", "CpuMeter", "cpu_seconds"]

CONTROL_PLANE = ("etcd", "kube-apiserver", "kube-controller-manager", "kube-scheduler", "kwok")
TICKS_PER_SECOND = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` so far (fields 14 and 15 of
    ``/proc/<pid>/stat``); None once it has gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / TICKS_PER_SECOND


def machine_busy_seconds() -> float:
    """CPU seconds all cores spent busy since boot (``/proc/stat``: all but idle and iowait)."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + values[4]
    return (sum(values[:8]) - idle) / TICKS_PER_SECOND


class CpuMeter:
    """``start()`` ... ``stop()``: CPU seconds per part between the two (``seconds``). The
    control plane's pids are looked up at ``start()``; a part whose process ended or was
    replaced in between is left out rather than guessed."""

    def __init__(self, extra: Mapping[str, int] | None = None) -> None:
        self.extra = dict(extra or {})
        self.seconds: dict[str, float] = {}
        self._pids: dict[str, int] = {}
        self._start: dict[str, float] = {}
        self._machine = 0.0

    def start(self) -> None:
        found = {name: _alive(name) for name in CONTROL_PLANE}
        self._pids = {n: p for n, p in found.items() if p is not None} | self.extra
        self._start = {n: s for n, p in self._pids.items() if (s := cpu_seconds(p)) is not None}
        self._machine = machine_busy_seconds()

    def stop(self) -> dict[str, float]:
        for name, before in self._start.items():
            after = cpu_seconds(self._pids[name])
            if after is not None and after >= before:
                self.seconds[name] = round(after - before, 2)
        self.seconds["machine"] = round(machine_busy_seconds() - self._machine, 2)
        return self.seconds
