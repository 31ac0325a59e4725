"""Compare plans over several seeds, as the paper's Fig. 8 does over 10 repetitions (IV-B).

Every plan is simulated with the same seeds, so all plans see the same task activity and noise
(common random numbers, see ``simulator``); medians over seeds are robust to the odd run.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Allocation, Problem

from .simulator import simulate

__all__ = ["PlanSummary", "compare"]


class PlanSummary(TypedDict):
    """Per plan; medians over seeds, None where no seed ran a cycle. JSON-ready."""

    miss_rate: float | None  # median over seeds of the overall miss rate
    module_miss_rate: dict[str, float | None]  # per module, median over seeds
    module_p95_cycle_s: dict[str, float | None]  # per module, median over seeds
    node_utilisation: dict[str, float | None]  # per node, median over seeds
    miss_rates: list[float | None]  # overall miss rate of each seed
    seeds: list[int]
    unplaced: list[str]  # instances the plan does not run


def _median(values: Iterable[float]) -> float | None:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.median(finite)) if finite else None


def compare(
    problem: Problem,
    plans: Mapping[str, tuple[NDArray[np.int64], Allocation]],
    duration_s: float = 120.0,
    seeds: Iterable[int] = range(10),
    *,
    all_active: bool = False,
    aligned_start: bool = False,
) -> dict[str, PlanSummary]:
    """Simulate each plan (placement, allocation) with every seed; summarise per plan.

    ``all_active``, ``aligned_start``: see ``simulate``.
    """
    seed_list = [int(s) for s in seeds]
    if not seed_list:
        raise ValueError("compare needs at least one seed")
    out: dict[str, PlanSummary] = {}
    for name, (placement, allocation) in plans.items():
        runs = [
            simulate(
                problem,
                placement,
                allocation,
                duration_s,
                s,
                all_active=all_active,
                aligned_start=aligned_start,
            )
            for s in seed_list
        ]
        first = runs[0]
        modules = list(first.module_miss_rate)
        out[name] = PlanSummary(
            miss_rate=_median(r.miss_rate for r in runs),
            module_miss_rate={m: _median(r.module_miss_rate[m] for r in runs) for m in modules},
            module_p95_cycle_s={m: _median(r.module_p95_cycle_s[m] for r in runs) for m in modules},
            node_utilisation={
                node: _median(float(r.node_utilisation[j]) for r in runs)
                for j, node in enumerate(first.node_names)
            },
            miss_rates=[None if math.isnan(r.miss_rate) else r.miss_rate for r in runs],
            seeds=seed_list,
            unplaced=[first.instance_labels[i] for i in first.unplaced],
        )
    return out
