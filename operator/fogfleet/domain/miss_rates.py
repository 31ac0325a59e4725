"""How fogfleet shows a miss rate, and which module of a plan is its worst (pure).

A miss rate is the fraction of a module's cycles that end after its deadline
(multi-robot-edge-cloud-scheduling III-D, F4). The models and the status keep the fraction
(0-1) for machines; everything a person reads (``kubectl get robotfleets``'s MISS column, the
CLI's tables, conditions and Events) shows it through :func:`format_miss_rate`, so a rate
reads the same everywhere. A measured rate of several modules or fleets is their cycles'
(:func:`pooled_miss_rate`), shown beside the prediction (the MEASURED column).

The **worst module** of a plan (:func:`worst_module`) is, in this order:

1. a module with an instance left unplaced (it runs no cycle there: every one is missed);
2. else the module with the highest miss rate in the figures shown (the plan's prediction
   in ``fogfleet plan``, the simulated rates in ``fogfleet simulate``);
3. rates that tie (a short simulation often sees no miss at all) go to the highest
   *predicted* rate of the same plan (III-D's model, ``module_miss_rates``);
4. then to the name that sorts first.

So ``plan`` and ``simulate`` name the same module for a plan whenever the simulation cannot
tell the modules apart, and differ only where the simulation saw misses the model ranks
otherwise (which is worth seeing).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

__all__ = ["format_miss_rate", "pooled_miss_rate", "worst_module"]

SMALLEST_SHOWN_PERCENT = 0.0001
"""Rates below this many percent show as ``<0.0001%`` (a prediction of 1e-24 is not news)."""


def format_miss_rate(rate: float | None) -> str:
    """A miss rate (fraction 0-1) as a percentage a person reads: ``-`` for none (no cycle
    ran), ``0%`` for exactly none missed, two significant digits below 1 % (``0.007%``, never
    ``0.00%`` for a rate that is not 0), one decimal from 1 % (``4.9%``, ``100.0%``)."""
    if rate is None or not math.isfinite(rate):
        return "-"
    percent = max(0.0, rate) * 100.0
    if percent == 0.0:
        return "0%"
    if percent < SMALLEST_SHOWN_PERCENT:
        return f"<{SMALLEST_SHOWN_PERCENT:g}%"
    if percent < 1.0:
        return f"{percent:.2g}%"
    return f"{percent:.1f}%"


def pooled_miss_rate(measures: Iterable[tuple[float | None, float]]) -> float | None:
    """The miss rate of several measured miss rates taken together, each weighed by its
    cycles: their missed cycles over their cycles (a fleet's modules, a module's fleets).
    ``measures``: (rate, cycles) pairs; a pair without a rate or without cycles was not
    measured and counts for nothing. None when nothing was measured, never 0: a rate of 0
    says that cycles ran and none was missed."""
    missed = cycles = 0.0
    for rate, n in measures:
        if rate is None or not math.isfinite(rate) or not n > 0:
            continue
        missed += rate * n
        cycles += n
    return missed / cycles if cycles > 0 else None


def worst_module(
    rates: Mapping[str, float | None],
    predicted: Mapping[str, float] | None = None,
    unplaced: Iterable[str] = (),
) -> str | None:
    """The plan's worst module by the rule of the module docstring: unplaced first, then the
    highest of ``rates`` (a NaN or None rate, no cycle ran, counts as the lowest), then the
    highest ``predicted`` rate, then the name. None for a plan without modules."""
    left_out = set(unplaced)
    names = set(rates) | left_out
    if not names:
        return None
    expected = predicted or {}

    def shown(m: str) -> float:
        r = rates.get(m)
        return r if r is not None and math.isfinite(r) else -1.0

    def model(m: str) -> float:
        p = expected.get(m)
        return p if p is not None and math.isfinite(p) else -1.0

    return min(names, key=lambda m: (m not in left_out, -shown(m), -model(m), m))
