"""``fogfleet bench budget`` (``make bench-plan-budget``): whether the first whole-fleet plan of a
large fleet keeps ``spec.scheduler.timeBudgetMillis``, and what a shorter budget costs.

The synthetic warehouse of ``robots`` robots x 8 modules on 0.4 ``robots`` edge nodes (as
``bench scale-plan``; 8000 instances on 1400 nodes at 1000 robots) is planned by
``solver.plan`` with the operator's default settings and each budget, ``runs`` times, the
budgets in a rotated order each run (the machine is shared: every budget sees its noise).
Columns per budget: the planner's seconds (``Schedule.duration_seconds``, what
``status.planningMillis`` reports), median and largest, and the largest over the budget
(target: at most 1.1); the generations run and the stages the budget cut (in any run); the
chosen plan's gap to the bound (``scheduling.gap``: S against the robot bound), median.

Then the same robots on a tenth as many edge nodes (100 at 1000 robots, the contended fleet
of ``bench why-live``), short of CPU: ``solver.plan`` finds no plan at full CPU and degrades
(``scheduling.degrade``) within the same budget, at ``short_budgets``; its rows add the
instances degraded (median; fewer is better) and have no gap (a degraded plan has none).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from typing import Any

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scale_plan import EDGES_PER_ROBOT
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.scheduling.exact import scalarised
from fogfleet.scheduling.gap import PlanGap, plan_gap
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import exact_weights, plan

__all__ = ["BUDGETS_MILLIS", "SHORT_BUDGETS_MILLIS", "budget_rows"]

BUDGETS_MILLIS = (5000, 8000, 12000, 20000)  # 20 s: the default
SHORT_BUDGETS_MILLIS = (8000, 20000)
SHORT_EDGES_PER_ROBOT = 0.1
Row = dict[str, Any]


def budget_rows(
    robots: int = 1000,
    budgets: Sequence[int] = BUDGETS_MILLIS,
    runs: int = 3,
    seed: int = 1,
    short_budgets: Sequence[int] = SHORT_BUDGETS_MILLIS,
) -> list[Row]:
    """One row per fleet and budget (see the module docstring)."""
    rows = _fleet_rows(robots, math.ceil(EDGES_PER_ROBOT * robots), budgets, runs, seed)
    if short_budgets:
        edges = math.ceil(SHORT_EDGES_PER_ROBOT * robots)
        rows += _fleet_rows(robots, edges, short_budgets, runs, seed)
    return rows


def _fleet_rows(robots: int, edges: int, budgets: Sequence[int], runs: int, seed: int) -> list[Row]:
    edges = max(2, edges)
    cat, fleet = synthetic_fleet(robots, edges, seed)
    problem = build_problem(fleet, cat)
    done: dict[int, list[Schedule]] = {b: [] for b in budgets}
    for run in range(runs):
        k = run % len(budgets)
        for budget in (*budgets[k:], *budgets[:k]):
            settings = SchedulerSettings(seed=seed, time_budget_millis=budget)
            done[budget].append(plan(problem, settings))
    settings = SchedulerSettings(seed=seed)
    w = exact_weights(problem, settings)
    one = done[budgets[0]][0]
    first = None if one.degraded else plan_gap(problem, one.placement, w)
    rows: list[Row] = []
    for budget in budgets:
        plans = done[budget]
        seconds = [s.duration_seconds for s in plans]
        cut = sorted({stage for s in plans for stage in s.budget_cut})
        chosen = [scalarised(problem, s.placement, w) for s in plans]
        gaps = [PlanGap(v, first.bound, first.kind, v) for v in chosen] if first is not None else []
        degraded = [s.degraded_instances for s in plans]
        rows.append(
            {
                "robots": robots,
                "edges": edges,
                "instances": problem.n_instances,
                "seed": seed,
                "budget_s": budget / 1000,
                "runs": len(plans),
                "seconds": round(statistics.median(seconds), 2),
                "seconds_max": round(max(seconds), 2),
                "over_budget_max": round(max(seconds) / (budget / 1000), 2),
                "generations": statistics.median(s.generations for s in plans),
                "budget_cut": ", ".join(cut) or "-",
                "feasible": all(s.feasible for s in plans),
                "degraded": statistics.median(degraded),
                "gap_pct": round(statistics.median(g.percent for g in gaps), 2) if gaps else None,
                "bound": first.kind if first is not None else None,
            }
        )
    return rows
