"""Missed-cycle rates over a window, from the workload's own counters in Prometheus.

Each module instance counts its cycles (``fogfleet_cycle_time_seconds_count``) and the cycles
that took longer than its cycle time (``fogfleet_missed_cycles_total``). A window's rate is the
difference of two snapshots, so it needs no range query and no extrapolation: per module,
missed / cycles over its instances; the fleet's rate is the mean over modules, the figure the
planner and the simulator report (``fogfleet.sim.simulator.fleet_miss_rate``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from fogfleet.sim.simulator import fleet_miss_rate

__all__ = [
    "Counts",
    "WindowRates",
    "counting_unrun",
    "simulated_rates",
    "snapshot",
    "window_rates",
]

CYCLES = "fogfleet_cycle_time_seconds_count"
MISSED = "fogfleet_missed_cycles_total"
Query = Callable[[str], list[dict[str, Any]]]
Key = tuple[str, str]  # (module, robot)


@dataclass(frozen=True)
class Counts:
    """Cycles and missed cycles per (module, robot) at one moment."""

    cycles: Mapping[Key, float]
    missed: Mapping[Key, float]


def _by_instance(query: Query, promql: str) -> dict[Key, float]:
    out: dict[Key, float] = {}
    for r in query(promql):
        m = r["metric"]
        out[(m.get("module", ""), m.get("robot", ""))] = float(r["value"][1])
    return out


def snapshot(query: Query, namespace: str) -> Counts:
    sel = f'{{namespace="{namespace}"}}'
    return Counts(
        cycles=_by_instance(query, f"sum by (module, robot) ({CYCLES}{sel})"),
        missed=_by_instance(query, f"sum by (module, robot) ({MISSED}{sel})"),
    )


@dataclass(frozen=True)
class WindowRates:
    """Miss rates over a window: per module, and the fleet's (mean over modules)."""

    modules: dict[str, float]
    cycles: dict[str, int]
    missed: dict[str, int] = field(default_factory=dict)

    @property
    def miss_rate(self) -> float:
        return fleet_miss_rate(self.modules)

    def pooled(self, modules: Iterable[str]) -> tuple[int, int]:
        """(missed, cycles) summed over ``modules``' instances (the paper's Fig. 9b metric
        pools the perception modules' cycles)."""
        names = [m for m in modules if m in self.cycles]
        return sum(self.missed.get(m, 0) for m in names), sum(self.cycles[m] for m in names)


def window_rates(before: Counts, after: Counts) -> WindowRates:
    """Rates between two snapshots; an instance missing from either counts nothing (it was
    not running through the window; ``run`` checks that every instance is there)."""
    cycles: dict[str, float] = {}
    missed: dict[str, float] = {}
    for key, end in after.cycles.items():
        if key not in before.cycles:
            continue
        module = key[0]
        cycles[module] = cycles.get(module, 0.0) + end - before.cycles[key]
        missed[module] = (
            missed.get(module, 0.0) + after.missed.get(key, 0.0) - before.missed.get(key, 0.0)
        )
    return _rates(cycles, missed)


def _rates(cycles: Mapping[str, float], missed: Mapping[str, float]) -> WindowRates:
    """Per module: missed / cycles (NaN where none ran), and both counts rounded."""
    return WindowRates(
        {m: (missed[m] / c if c > 0 else math.nan) for m, c in cycles.items()},
        {m: round(c) for m, c in cycles.items()},
        {m: round(x) for m, x in missed.items()},
    )


def counting_unrun(rates: WindowRates, due: Mapping[str, float]) -> WindowRates:
    """``rates`` with the cycles of instances that never ran in the window counted as missed
    (``due``: module -> the cycles its unrun instances were due, ``window / cycle time`` each;
    the protocol's Pending rule). A module with no instance running is all misses."""
    cycles = {m: float(c) for m, c in rates.cycles.items()}
    missed = {m: float(rates.missed.get(m, 0)) for m in rates.cycles}
    for module, n in due.items():
        cycles[module] = cycles.get(module, 0.0) + n
        missed[module] = missed.get(module, 0.0) + n
    return _rates(cycles, missed)


def simulated_rates(rates: Mapping[str, float], cycles: Mapping[str, int]) -> WindowRates:
    """The simulator's per-module rates and cycles as a ``WindowRates`` (a module none of
    whose instances ran has no cycles and misses none)."""
    return WindowRates(
        dict(rates),
        {m: int(c) for m, c in cycles.items()},
        {m: round(rates[m] * c) if c else 0 for m, c in cycles.items()},
    )
