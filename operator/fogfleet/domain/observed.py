"""Learning a module's execution-time profile from what runs, and telling drift (issue 10;
pure).

The declared profile (multi-robot-edge-cloud-scheduling III-E "Prior Data", Fig. 3: mean and
std execution time per hardware type and CPU) is the prior. What runs is measured per
(module, hardware type, CPU limit): count, mean and 95th percentile of the execution time.

**The correction** of a module's profile on one hardware type is one factor, the measured
over the declared mean, blended with the prior by sample count::

    factor = (prior x 1 + sum_i n_i x mean_i / declared_i) / (prior + sum_i n_i)

where ``declared_i`` is the declared row the module ran with (the largest profiled CPU at or
below its limit, as the workload picks it). One factor per hardware type, not per row: a
module measured three times slower than declared at 100m is, until measured there, taken to
be three times slower at 200m too, so the re-plan can move it to a row it never ran with.
The planner multiplies every declared row of that hardware type (mean and std) by it.

**Drift** is a module's measured miss rate above the plan's prediction by more than the
margin; it counts once it has lasted ``forSeconds``, and a fleet re-plans for it at most
every ``minIntervalSeconds`` (no flapping: after a re-plan the measures start again).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from .pairs import ProfileRow

__all__ = [
    "Z95",
    "ModuleDrift",
    "Observation",
    "correction",
    "declared_row",
    "drift_due",
    "drifting",
]

Z95 = 1.645  # the normal distribution's 95th percentile, in standard deviations


@dataclass(frozen=True)
class Observation:
    """A module's execution times on one hardware type with one CPU limit, over a window."""

    module: str
    hardware_type: str
    cpu: float | None  # cores; None: no limit
    count: float
    mean: float  # seconds
    p95: float  # seconds

    @property
    def std(self) -> float:
        """From the 95th percentile, as if the tail were normal (a histogram has no std)."""
        return max(0.0, (self.p95 - self.mean) / Z95)


@dataclass(frozen=True)
class ModuleDrift:
    """One module of a fleet: predicted and measured miss rate, since when it drifts."""

    predicted: float
    measured: float | None
    cycles: float
    since: float | None  # wall time; None: not drifting


def declared_row(rows: Sequence[ProfileRow], cpu: float | None) -> ProfileRow | None:
    """The row a module runs with under ``cpu``: the largest profiled CPU at or below it, the
    smallest if none is; the largest without a limit (``workload.spec.exec_time``)."""
    if not rows:
        return None
    ordered = sorted(rows, key=lambda r: r.cpu)
    if cpu is None:
        return ordered[-1]
    fits = [r for r in ordered if r.cpu <= cpu + 1e-9]
    return fits[-1] if fits else ordered[0]


def correction(
    observations: Iterable[Observation],
    declared: Mapping[str, Sequence[ProfileRow]],
    prior: float,
) -> dict[str, tuple[float, float]]:
    """Hardware type -> (factor, measured cycles) for the observations of one module (see the
    module docstring); types without a declared row or a measured cycle have none."""
    sums: dict[str, tuple[float, float]] = {}
    for obs in observations:
        row = declared_row(declared.get(obs.hardware_type, ()), obs.cpu)
        if row is None or row.mean <= 0 or obs.count <= 0:
            continue
        n, weighted = sums.get(obs.hardware_type, (0.0, 0.0))
        sums[obs.hardware_type] = (n + obs.count, weighted + obs.count * obs.mean / row.mean)
    return {hw: ((prior + weighted) / (prior + n), n) for hw, (n, weighted) in sorted(sums.items())}


def drifting(predicted: float, measured: float | None, margin_percent: float) -> bool:
    """Whether a module misses more than its plan predicts by more than the margin."""
    return measured is not None and measured - predicted > margin_percent / 100.0


def drift_due(
    since: float | None,
    now: float,
    for_seconds: float,
    last_replan: float | None,
    min_interval_seconds: float,
) -> bool:
    """Whether a drift that began at ``since`` re-plans the fleet now."""
    if since is None or now - since < for_seconds:
        return False
    return last_replan is None or now - last_replan >= min_interval_seconds
