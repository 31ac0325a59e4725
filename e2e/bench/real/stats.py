"""The statistics of the real-nodes comparison: a reduction of medians, its bootstrap CI and a
one-sided rank test (pure; stdlib and numpy).

The protocol compares six runs per arm, so both tools are chosen for small samples whose
rates are often exactly 0.0 (ties): the percentile bootstrap needs no normality, and the
Mann-Whitney p value comes from the exact permutation distribution of U, ties included,
instead of a table that assumes distinct values.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

__all__ = ["EXACT_LIMIT", "bootstrap_reduction_ci", "mann_whitney_less", "reduction"]

# above this many splits of the pooled sample the p value comes from the normal approximation
EXACT_LIMIT = 2_000_000


def _sample(values: Sequence[float], name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name}: need a non-empty sequence of numbers, got {values!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: every value must be finite, got {values!r}")
    return arr


def reduction(treated_median: float, control_median: float) -> float:
    """1 - treated / control: the share of the control's misses the treatment avoids
    (NaN when the control has none, where a reduction means nothing)."""
    if control_median == 0 or math.isnan(control_median):
        return math.nan
    return 1.0 - treated_median / control_median


def bootstrap_reduction_ci(
    treated: Sequence[float],
    control: Sequence[float],
    *,
    resamples: int = 10000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap CI of ``reduction(median(treated), median(control))``.

    Each arm is resampled with replacement on its own (the arms are independent runs), and
    the CI is the (1 - level)/2 and (1 + level)/2 percentiles of the resampled reductions
    (Efron & Tibshirani 1993, *An Introduction to the Bootstrap*, ch. 13: the percentile
    interval needs no distributional assumption and respects the ratio's skew). Resamples
    whose control median is 0 have no reduction and are skipped; if all are, (nan, nan).
    """
    t, c = _sample(treated, "treated"), _sample(control, "control")
    if resamples < 1 or not 0 < level < 1:
        raise ValueError(f"need resamples >= 1 and 0 < level < 1, got {resamples}, {level}")
    rng = np.random.default_rng(seed)
    t_med = np.median(rng.choice(t, size=(resamples, t.size), replace=True), axis=1)
    c_med = np.median(rng.choice(c, size=(resamples, c.size), replace=True), axis=1)
    keep = c_med != 0
    if not keep.any():
        return (math.nan, math.nan)
    reductions = 1.0 - t_med[keep] / c_med[keep]
    lo, hi = np.percentile(reductions, [50 * (1 - level), 50 * (1 + level)])
    return (float(lo), float(hi))


def _doubled_midranks(pooled: np.ndarray) -> list[int]:
    """2 x the mid-rank of each value (ties share the mean of their ranks): integers, so sums
    compare exactly."""
    order = np.argsort(pooled, kind="stable")
    ranks = [0] * pooled.size
    i = 0
    while i < pooled.size:
        j = i
        while j + 1 < pooled.size and pooled[order[j + 1]] == pooled[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[int(order[k])] = (i + 1) + (j + 1)  # 2 x mean of ranks i+1 .. j+1
        i = j + 1
    return ranks


def _normal_less(u: float, n1: int, n2: int, pooled: np.ndarray) -> float:
    """P(U <= u) under the normal approximation with tie correction and a continuity
    correction of 1/2 (Lehmann 1975, *Nonparametrics*, ch. 1.4)."""
    n = n1 + n2
    _, counts = np.unique(pooled, return_counts=True)
    ties = float(np.sum(counts.astype(float) ** 3 - counts))
    var = n1 * n2 / 12.0 * ((n + 1) - ties / (n * (n - 1)))
    if var <= 0:  # every value tied: U cannot tell the arms apart
        return 1.0
    z = (u + 0.5 - n1 * n2 / 2.0) / math.sqrt(var)
    return min(1.0, 0.5 * math.erfc(-z / math.sqrt(2)))


def mann_whitney_less(treated: Sequence[float], control: Sequence[float]) -> float:
    """One-sided p value of the Mann-Whitney U test (Mann & Whitney 1947, *Ann. Math.
    Statist.* 18:50-60) for "treated tends to be smaller than control".

    U counts the (treated, control) pairs where treated is larger, a tie counting 1/2
    (equivalently U = R - n1(n1 + 1)/2 with R the treated's sum of mid-ranks); small U speaks
    for the treatment. The p value is P(U <= observed) over every split of the pooled
    sample into groups of the arms' sizes, each equally likely under the null: an exact
    permutation distribution, so ties (several 0.0 rates) are handled exactly. Six against
    six, all treated smaller: 1/C(12, 6) = 1/924.

    When there are more than ``EXACT_LIMIT`` splits, the p value falls back to the normal
    approximation with tie and continuity corrections.
    """
    t, c = _sample(treated, "treated"), _sample(control, "control")
    pooled = np.concatenate([t, c])
    ranks = _doubled_midranks(pooled)
    observed = sum(ranks[: t.size])  # 2R for the treated
    if math.comb(pooled.size, t.size) > EXACT_LIMIT:
        u = observed / 2 - t.size * (t.size + 1) / 2
        return _normal_less(u, t.size, c.size, pooled)
    total = at_most = 0
    for split in itertools.combinations(ranks, t.size):
        total += 1
        at_most += sum(split) <= observed
    return at_most / total
