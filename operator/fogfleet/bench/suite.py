"""``fogfleet bench scheduling``: the scheduling benchmarks in one table.

1. Missed cycles in the simulator, warehouse fleet, several seeds: nsga2 vs k8s-default (the
   emulated kube-scheduler placement of plain Deployments) vs onboard, median over seeds. Two
   activity modes: every module active all the time (the paper's IV-B setting for "K8s
   default", "GA-based" and "GA-based with limits") and the Table II activation rates ("GA-based
   with TA").
2. Optimality gap of nsga2 to the exact MILP optimum of the scalarised objective.
3. Decision time: warehouse fleet and 100 robots x 8 modules on 40 edge nodes.
4. The paper's plain NSGA-II vs ours at ~1000 genes (feasibility and gap to the LP bound).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench import scheduling as sbench
from fogfleet.domain.miss_rates import format_miss_rate, worst_module
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.solver import plan
from fogfleet.sim import simulate

__all__ = ["format_scheduling", "miss_rates", "run_scheduling"]

SCHEDULERS = ("nsga2", "k8s-default", "onboard")


def miss_rates(
    seeds: Sequence[int] = tuple(range(1, 11)),
    duration_s: float = 120.0,
    problem: Problem | None = None,
) -> list[dict[str, Any]]:
    """Median simulated missed-cycle rate per scheduler and activity mode; each seed plans and
    simulates anew (the plan's seed and the simulation's seed are the same number)."""
    p = problem or sbench.warehouse_problem()
    rates: dict[tuple[str, bool], list[float]] = {}
    module_rates: dict[tuple[str, bool], dict[str, list[float]]] = {}
    for seed in seeds:
        for name in SCHEDULERS:
            s = plan(p, SchedulerSettings(algorithm=name, seed=seed))
            alloc = p.allocation(s.with_limits)
            for all_active in (True, False):
                r = simulate(
                    p, s.placement, alloc, duration_s=duration_s, seed=seed, all_active=all_active
                )
                rates.setdefault((name, all_active), []).append(r.miss_rate)
                per = module_rates.setdefault((name, all_active), {})
                for m, v in r.module_miss_rate.items():
                    per.setdefault(m, []).append(v)
    rows: list[dict[str, Any]] = []
    for all_active in (True, False):
        base = statistics.median(rates[("k8s-default", all_active)])
        for name in SCHEDULERS:
            med = statistics.median(rates[(name, all_active)])
            per = module_rates[(name, all_active)]
            medians = {m: statistics.median(v) for m, v in per.items()}
            worst = worst_module(medians) or "-"
            rows.append(
                {
                    "bench": "missed-cycles",
                    "activity": "all-active" if all_active else "table-II",
                    "scheduler": name,
                    "seeds": len(seeds),
                    "missRate_median": round(med, 5),
                    "vs_k8s_default": f"{100 * (med - base) / base:+.1f}%" if base > 0 else "n/a",
                    "worst_module": f"{worst} {format_miss_rate(medians.get(worst))}",
                }
            )
    return rows


def run_scheduling(runs: int = 5, quick: bool = False) -> dict[str, list[dict[str, Any]]]:
    if quick:
        return {
            "missed-cycles": miss_rates(seeds=(1, 2), duration_s=30.0),
            "decision-time": sbench.decision_time(repeats=1, robots=20, edges=8),
        }
    return {
        "missed-cycles": miss_rates(seeds=tuple(range(1, 11))),
        "optimality-gap": sbench.optimality_gap(seeds=tuple(range(1, runs + 1))),
        "decision-time": sbench.decision_time(repeats=runs),
        "standin": sbench.standin(),
    }


def format_scheduling(report: dict[str, list[dict[str, Any]]]) -> str:
    parts = []
    for title, rows in report.items():
        parts.append(f"== {title}\n{sbench.format_table(rows)}")
    return "\n\n".join(parts)
