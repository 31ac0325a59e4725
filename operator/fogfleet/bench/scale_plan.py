"""First whole-fleet plan benchmark (``fogfleet bench scale-plan``, ``make bench-scale-plan``):
the plan a new leader, a large spec change or ``kubectl fogfleet plan --what-if`` waits for.

Per seed, the synthetic warehouse of ``robots`` robots x 8 modules on ceil(0.4 robots) edge
nodes (``scheduling.synthetic_fleet``, the proportions ``make bench-scale`` uses; at 1000
robots 8000 instances on 1400 nodes) is planned by NSGA-II with the operator's default
settings two ways, in the same run:

- *priced plan*: the warm start (the repaired seed plans with a few genes re-drawn,
  ``operators.warm_population``, and ``convergence.WARM_GENERATIONS`` generations, what
  ``plan`` does from ``operators.WARM_START_GENES`` genes on), then the levelled plans and
  the robot bound's priced plan (``configurations.priced_plan``) in the archive;
- *warm start (before)*: the same without the priced plan, the search before it.

Both end with the peak levelling and the Pareto local search. Columns: seconds and CPU
seconds (median of ``runs`` on the first seed, one run on the others), generations, the best
scalarised S on the front (``exact.scalarised``: multi-robot-edge-cloud-scheduling III-B's
objectives weighted as the MILP weighs them) and the chosen plan's, the LP relaxation's bound
(``exact.lp_bound``, a lower bound on any plan's S) and both gaps to it, the robot bound
(``configurations.robot_bound``: robots' instances are whole, which the LP ignores; a tighter lower
bound, 2-4 % above the LP's on this fleet) and the best plan's gap to it, and the process's
peak resident memory after the row (the priced plan runs first, so its figure is its own; the
LP bound is solved after both plans).
"""

from __future__ import annotations

import math
import resource
import statistics
import time
from collections.abc import Sequence
from typing import Any

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.configurations import robot_bound
from fogfleet.scheduling.exact import lp_bound, scalarised
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import nsga2

__all__ = ["EDGES_PER_ROBOT", "VARIANTS", "scale_plan_rows"]

EDGES_PER_ROBOT = 0.4  # as e2e/bench/scale.py and bench.replan
VARIANTS = (("priced plan", True), ("warm start (before)", False))
Row = dict[str, Any]


def _peak_rss_mb() -> int:
    """The process's peak resident memory so far (Linux reports kibibytes)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def _timed(
    problem: Problem, seed: int, priced: bool, runs: int
) -> tuple[Schedule, list[float], list[float]]:
    """The last of ``runs`` plans, and each run's wall and CPU seconds (on a machine shared
    with other work the CPU seconds say more about the planner than the wall ones)."""
    times, cpu, last = [], [], None
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        last = nsga2(problem, SchedulerSettings(seed=seed), warm_start=True, priced=priced)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    assert last is not None
    return last, times, cpu


def scale_plan_rows(
    robots: int = 1000, seeds: Sequence[int] = (1, 2, 3, 4, 5), runs: int = 3
) -> list[Row]:
    """One row per (seed, variant); see the module docstring."""
    rows: list[Row] = []
    for n, seed in enumerate(seeds):
        cat, fleet = synthetic_fleet(robots, max(2, math.ceil(EDGES_PER_ROBOT * robots)), seed)
        done: list[tuple[Row, Schedule]] = []
        for name, priced in VARIANTS:
            # a problem of its own: the first plan of a problem fills its cached tables, a
            # cost each variant's first run pays alike (not only the variant run first)
            problem = build_problem(fleet, cat)
            s, times, cpu = _timed(problem, seed, priced, runs if n == 0 else 1)
            plans = s.pareto_placements if s.pareto_placements is not None else [s.placement]
            row: Row = {
                "robots": robots,
                "instances": problem.n_instances,
                "nodes": problem.n_nodes,
                "seed": seed,
                "variant": name,
                "seconds": round(statistics.median(times), 2),
                "cpu_seconds": round(statistics.median(cpu), 2),
                "runs": len(times),
                "generations": s.generations,
                "feasible": s.feasible,
                "best_S": round(min(scalarised(problem, x) for x in plans), 5),
                "chosen_S": round(scalarised(problem, s.placement), 5),
                "peak_rss_MB": _peak_rss_mb(),
            }
            done.append((row, s))
        bound = lp_bound(problem)
        whole = robot_bound(problem)
        for row, _ in done:
            row["lp_bound_S"] = round(bound, 5)
            row["gap_pct"] = round(100 * (row["best_S"] - bound) / bound, 2)
            row["chosen_gap_pct"] = round(100 * (row["chosen_S"] - bound) / bound, 2)
            if whole is not None:
                row["robot_bound_S"] = round(whole, 5)
                row["robot_gap_pct"] = round(100 * (row["best_S"] - whole) / whole, 2)
            rows.append(row)
    return rows
