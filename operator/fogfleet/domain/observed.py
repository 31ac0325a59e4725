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

**Evidence** (issue 49: a loop that never moves on noise). The noise is a fit to a tail, and a
tail is measured by its misses, which are few: 2 misses in 140 cycles say the share is
somewhere between 0.5 % and 4 %. A re-plan moves a module off the hardware type whose noise it
learnt toward one it never ran on (whose noise is the prior's, none), so a noise fitted to
the ratio of a few misses moves modules on luck. So the learnt noise is the one the evidence
certainly shows:

- each row's sigma is fitted to the lower end of the one-sided 95 % confidence bound of its
  share of misses over the cycles seen (``miss_share_bound``: the Wilson score bound of a
  binomial share), not to the ratio; a well-measured share barely moves (486 of 5400: 9.0 %
  -> 8.4 %), a few misses fall far (2 of 140: 1.4 % -> 0.5 %);
- a hardware type's noise counts only from ``spec.drift.minCycles`` cycles there (default
  1000, a 10 Hz module's 100 s: at 1 % missed, ten misses to fit the tail to); until then it
  is not known there (``Learnt.noise_cycles`` 0);
- where the noise is not known (a type the module never ran on, or too few cycles), the
  planner takes the largest noise the module showed on another type, not none
  (``rows.carry_noise``). Both bounds above shrink the noise where it was measured, but the
  gain of a move is the difference between two types, and the prior's zero on the type it
  never ran on is the most optimistic end of that difference: with it, any noise learnt made
  every unmeasured node look better by exactly that noise. 2 misses in 599 cycles (0.33 %)
  of a 60 +- 6 ms pose estimator in a 100 ms cycle, the bed's re-run of issue 49, are a
  13.4 ms noise by their ratio; over 1000 cycles or more (two instances' warm-up) the
  Wilson bound still leaves 11.6 ms (1200 cycles, 4 missed), a predicted 0.11 % on the edge
  it runs on against none on an edge it never ran on: the move the bed made, and that missed
  more. With the noise carried both sides miss alike and the move gains nothing.

The factor is a mean, not a tail: it is measured by every sample, is already held back by the
prior, and a large error (a module four times slower than declared, which misses nearly every
cycle) still corrects the profile at once; it is not carried to other types. The predicted
gain of a move is the planner's, on rows so corrected: the noise where it was measured at the
lower end of its bound, where it was not at the largest shown elsewhere, so the gain is the
lower end of what the evidence supports. A move must beat the migration margin with it (the
cost of moving), and twice it to return an instance to the node it was last moved off
(``scheduling.stickiness``: no back and forth).

**Drift** is a module's measured miss rate above the plan's prediction by more than what the
module can afford (:func:`miss_budget`), which its real-time class decides
(multi-robot-edge-cloud-scheduling III-A 2: a hard real-time module's missed deadline "can
lead to catastrophic results or system failure", a soft one's "might lead to performance
degradation", a non-real-time one's "usually do[es] not")::

    drift  <=>  measured - predicted > share(class) x spec.drift.marginPercent / 100

    share: hard real-time or safety-critical 1/100, soft real-time 1, none 2

With the default margin of 5: 0.05 percentage points for a hard real-time controller (4.9 %
missed against 0.007 % predicted is drift), 5 points for a soft module (noise around its
prediction is not), 10 points for a non-real-time one. It counts once it has lasted
``forSeconds``, and a fleet re-plans for it at most every ``minIntervalSeconds`` (no
flapping: after a re-plan the measures start again).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.observed import DriftSettings
from fogfleet.api.v1alpha1.softwaremodule import RealtimeClass, Taxonomy, must_run_on_board

from .problem import Problem
from .rows import Learnt, ProfileRow

__all__ = [
    "MIN_CYCLES",
    "SOFT_BUDGET",
    "Z95",
    "MissBudget",
    "ModuleDrift",
    "Observation",
    "Timing",
    "correction",
    "cycle_noise",
    "declared_row",
    "drift_due",
    "drifting",
    "miss_budget",
    "miss_share_bound",
    "timings",
]

Z95 = 1.645  # the normal distribution's 95th percentile, in standard deviations
MIN_CYCLES = int(DriftSettings.model_fields["min_cycles"].default)  # spec.drift.minCycles


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
class MissBudget:
    """What a module can miss above its predicted rate before it drifts (module docstring)."""

    allowance: float  # fraction of its cycles (0-1)
    realtime: str  # its class, as people say it: "hard real-time", "soft real-time", ...

    def describe(self) -> str:
        """ "0.05 points (hard real-time)"."""
        return f"{self.allowance * 100:.3g} points ({self.realtime})"


# The share of spec.drift.marginPercent each real-time class affords (III-A 2).
HARD_SHARE, SOFT_SHARE, NONE_SHARE = 0.01, 1.0, 2.0


def miss_budget(taxonomy: Taxonomy | None, margin_percent: float) -> MissBudget:
    """The module's drift allowance: its real-time class's share of ``margin_percent``
    (a safety-critical module counts as hard real-time, as III-B keeps both on board); a
    module whose taxonomy is unknown gets the soft real-time share."""
    if taxonomy is not None and must_run_on_board(taxonomy):
        share, label = HARD_SHARE, "hard real-time"
        if taxonomy.realtime is not RealtimeClass.HARD:
            label = "safety-critical"
    elif taxonomy is not None and taxonomy.realtime is RealtimeClass.NONE:
        share, label = NONE_SHARE, "non-real-time"
    else:
        share, label = SOFT_SHARE, "soft real-time"
    return MissBudget(share * margin_percent / 100.0, label)


SOFT_BUDGET = miss_budget(None, 5.0)
"""The default margin's budget of a module whose taxonomy is unknown."""


@dataclass(frozen=True)
class ModuleDrift:
    """One module of a fleet: predicted and measured miss rate, since when it drifts, and
    the budget it was judged by."""

    predicted: float
    measured: float | None
    cycles: float
    since: float | None  # wall time; None: not drifting
    budget: MissBudget = SOFT_BUDGET


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


def miss_share_bound(missed: float, cycles: float, z: float = Z95) -> float:
    """The lower end of the one-sided confidence bound (``z`` std, 95 % by default) of the
    share of missed cycles, ``missed`` of ``cycles``: the Wilson score bound of a binomial
    share (each cycle misses or not; III-D's miss probability is that share's model). A few
    misses in a few hundred cycles bound the share far below their ratio; a well-measured
    share keeps its ratio."""
    if cycles <= 0:
        return 0.0
    p, zz = min(max(missed / cycles, 0.0), 1.0), z * z
    centre = p + zz / (2 * cycles)
    half = z * math.sqrt(p * (1 - p) / cycles + zz / (4 * cycles * cycles))
    return max(0.0, (centre - half) / (1 + zz / cycles))


def correction(
    observations: Iterable[Observation],
    declared: Mapping[str, Sequence[ProfileRow]],
    prior: float,
    timing: Mapping[str, Timing] | None = None,
    min_cycles: float = MIN_CYCLES,
) -> dict[str, tuple[Learnt, float]]:
    """Hardware type -> (correction, measured cycles) for the observations of one module (see
    the module docstring); types without a declared row or a measured cycle have none. The
    noise needs the module's ``timing`` on the type (none: no noise learnt there) and
    ``min_cycles`` cycles there (fewer: none learnt, ``noise_cycles`` 0: not known there; see
    "Evidence" in the module docstring)."""
    seen = list(observations)
    factors = _factors(seen, declared, prior)
    noise = _noise(seen, declared, timing or {}, factors)
    out = {}
    for hw, (factor, n) in sorted(factors.items()):
        m, var = noise.get(hw, (0.0, 0.0))
        known = m >= max(min_cycles, 1.0)
        sigma = math.sqrt(var / (prior + m)) if known else 0.0
        out[hw] = (Learnt(factor, sigma, m if known else 0.0), n)
    return out


def _factors(
    seen: Sequence[Observation], declared: Mapping[str, Sequence[ProfileRow]], prior: float
) -> dict[str, tuple[float, float]]:
    """Hardware type -> (factor, measured count): the blend of the module docstring."""
    sums: dict[str, tuple[float, float]] = {}
    for obs in seen:
        row = declared_row(declared.get(obs.hardware_type, ()), obs.cpu)
        if row is None or row.mean <= 0 or obs.count <= 0:
            continue
        n, weighted = sums.get(obs.hardware_type, (0.0, 0.0))
        sums[obs.hardware_type] = (n + obs.count, weighted + obs.count * obs.mean / row.mean)
    return {hw: ((prior + w) / (prior + n), n) for hw, (n, w) in sums.items()}


def _noise(
    seen: Sequence[Observation],
    declared: Mapping[str, Sequence[ProfileRow]],
    timing: Mapping[str, Timing],
    factors: Mapping[str, tuple[float, float]],
) -> dict[str, tuple[float, float]]:
    """Hardware type -> (cycles, sum of cycles x sigma^2), each row's sigma fitted to the
    lower end of its miss share's confidence bound (``miss_share_bound``)."""
    noise: dict[str, tuple[float, float]] = {}
    for obs in seen:
        hw, t = obs.hardware_type, timing.get(obs.hardware_type)
        row = declared_row(declared.get(hw, ()), obs.cpu)
        if t is None or row is None or hw not in factors or obs.cycles < 1:
            continue
        share = miss_share_bound(obs.missed, obs.cycles)
        sigma = cycle_noise(share, t, Learnt(factors[hw][0]).row(row))
        if sigma is not None:
            n, weighted = noise.get(hw, (0.0, 0.0))
            noise[hw] = (n + obs.cycles, weighted + obs.cycles * sigma * sigma)
    return noise


def drifting(predicted: float, measured: float | None, budget: MissBudget) -> bool:
    """Whether a module misses more than its plan predicts by more than it can afford
    (``miss_budget``)."""
    return measured is not None and measured - predicted > budget.allowance


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
