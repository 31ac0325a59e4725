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

**The cycle's noise.** A cycle is more than its work: a ROS 2 module wakes up late, its
middleware receives and publishes, the node's other processes and the host take the CPU for a
moment. The model of eq. 4 has none of it (a same-node input costs nothing), so a module
whose work fits its cycle with little slack is predicted never to miss and may miss often.
Each observation also counts the cycles and misses of the module with that hardware type and
CPU limit; where it missed, the correction carries a **noise**: the standard deviation
``sigma`` of an extra normal term in the cycle time such that the model's tail at the
deadline equals the measured share of misses (III-D's miss probability, with
``mu = t_net + f x declared mean``)::

    sigma_total = (T - mu) / z(1 - missed / cycles)
    sigma^2     = sigma_total^2 - (f x std)^2 - std_net^2

blended with the prior (no noise) by cycle count like the factor:
``sigma^2 = sum n_i sigma_i^2 / (prior + sum n_i)``. It is the same on every row of that
hardware type (what a cycle costs besides its work does not shrink with the work), so the
planner adds it to each row's std and gives a module the CPU that leaves room for it. Where
the mean alone misses (``mu >= T``) or half the cycles miss, the factor explains it and the
observation adds no noise.

**Drift** is a module's measured miss rate above the plan's prediction by more than the
margin; it counts once it has lasted ``forSeconds``, and a fleet re-plans for it at most
every ``minIntervalSeconds`` (no flapping: after a re-plan the measures start again).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray

from .problem import Problem
from .rows import Learnt, ProfileRow

__all__ = [
    "Z95",
    "ModuleDrift",
    "Observation",
    "Timing",
    "correction",
    "cycle_noise",
    "declared_row",
    "drift_due",
    "drifting",
    "timings",
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
    cycles: float = 0.0  # the module's cycles with this hardware type and CPU limit
    missed: float = 0.0  # ... of them longer than its cycle time

    @property
    def std(self) -> float:
        """From the 95th percentile, as if the tail were normal (a histogram has no std)."""
        return max(0.0, (self.p95 - self.mean) / Z95)


@dataclass(frozen=True)
class Timing:
    """What the model puts around a module's work on one hardware type: its cycle time and
    its instances' transfer times there (eq. 4's t_in + t_out), seconds."""

    cycle: float
    net_mean: float = 0.0
    net_std: float = 0.0


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


def cycle_noise(missed_share: float, timing: Timing, row: ProfileRow) -> float | None:
    """The std of the cycle's noise (seconds) that makes the model's miss probability of a
    cycle with work ``row`` equal ``missed_share`` (module docstring); None where the noise
    cannot tell (the mean reaches the deadline, or half the cycles or more miss)."""
    slack = timing.cycle - timing.net_mean - row.mean
    if slack <= 0 or not 0.0 <= missed_share < 0.5:
        return None
    if missed_share == 0.0:
        return 0.0
    total = slack / NormalDist().inv_cdf(1.0 - missed_share)
    return math.sqrt(max(0.0, total * total - row.std * row.std - timing.net_std**2))


def timings(problem: Problem, placement: NDArray[np.integer], module: str) -> dict[str, Timing]:
    """Hardware type -> the Timing of ``module``'s instances placed on nodes of that type
    (their mean cycle and transfer times under ``placement``)."""
    groups: dict[str, list[tuple[float, float, float]]] = {}
    for i, inst in enumerate(problem.instances):
        j = int(placement[i])
        if inst.module == module and j >= 0:
            hw = problem.nodes[j].hardware_type
            net = (float(problem.net_mean[i, j]), float(problem.net_std[i, j]))
            groups.setdefault(hw, []).append((float(problem.cycle[i]), *net))
    return {
        hw: Timing(*(sum(col) / len(col) for col in zip(*rows, strict=True)))
        for hw, rows in sorted(groups.items())
    }


def correction(
    observations: Iterable[Observation],
    declared: Mapping[str, Sequence[ProfileRow]],
    prior: float,
    timing: Mapping[str, Timing] | None = None,
) -> dict[str, tuple[Learnt, float]]:
    """Hardware type -> (correction, measured cycles) for the observations of one module (see
    the module docstring); types without a declared row or a measured cycle have none. The
    noise needs the module's ``timing`` on the type (none: no noise learnt there)."""
    seen = list(observations)
    sums: dict[str, tuple[float, float]] = {}
    for obs in seen:
        row = declared_row(declared.get(obs.hardware_type, ()), obs.cpu)
        if row is None or row.mean <= 0 or obs.count <= 0:
            continue
        n, weighted = sums.get(obs.hardware_type, (0.0, 0.0))
        sums[obs.hardware_type] = (n + obs.count, weighted + obs.count * obs.mean / row.mean)
    factors = {hw: (prior + weighted) / (prior + n) for hw, (n, weighted) in sums.items()}
    noise: dict[str, tuple[float, float]] = {}  # hw -> (cycles, sum of cycles x sigma^2)
    for obs in seen:
        hw, t = obs.hardware_type, (timing or {}).get(obs.hardware_type)
        row = declared_row(declared.get(hw, ()), obs.cpu)
        if t is None or row is None or hw not in factors or obs.cycles < 1:
            continue
        sigma = cycle_noise(obs.missed / obs.cycles, t, Learnt(factors[hw]).row(row))
        if sigma is not None:
            n, weighted = noise.get(hw, (0.0, 0.0))
            noise[hw] = (n + obs.cycles, weighted + obs.cycles * sigma * sigma)
    out = {}
    for hw, (n, _) in sorted(sums.items()):
        m, var = noise.get(hw, (0.0, 0.0))
        sigma = math.sqrt(var / (prior + m)) if m > 0 else 0.0
        out[hw] = (Learnt(factors[hw], sigma), n)
    return out


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
