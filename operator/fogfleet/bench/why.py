"""``fogfleet bench why`` (``make bench-why``): how long ``kubectl fogfleet why`` computes on a
large fleet.

The synthetic warehouse (``scheduling.synthetic_fleet``: n robots x 8 modules on 0.4 n edge
nodes) with a placement from the greedy heuristic (what runs does not change the cost). Per
size, the median of ``runs`` timings of each step ``why FLEET MODULE --robot R`` takes after
reading the objects: the problem build (``domain.build.build_problem``, the operator's own),
the build's refusals for the instance (``domain.build.refusals``) and the explanation
(``scheduling.explain.alternatives.explain_module``: every node the instance could use, each
move scored incrementally); then the explanation of a shared module's replicas (no ``--robot``).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem, refusals
from fogfleet.scheduling.explain.alternatives import explain_module
from fogfleet.scheduling.heuristics import greedy_schedule

__all__ = ["why_rows"]

EDGES_PER_ROBOT = 0.4  # as bench.replan and e2e/bench/scale.py
Row = dict[str, Any]


def _median(runs: int, step: Callable[[], object]) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return round(statistics.median(times), 3)


def why_rows(sizes: tuple[int, ...] = (1000,), runs: int = 5, seed: int = 1) -> list[Row]:
    """One row per fleet size (see the module docstring)."""
    return [_row(robots, runs, seed) for robots in sizes]


def _row(robots: int, runs: int, seed: int) -> Row:
    cat, fleet = synthetic_fleet(robots, max(2, round(EDGES_PER_ROBOT * robots)), seed)
    problem = build_problem(fleet, cat)
    x = greedy_schedule(problem, SchedulerSettings(seed=seed)).placement
    robot = fleet.spec.robots[robots // 2]
    per_robot = next(m for m in problem.module_names if m.startswith("scene"))
    i = next(
        k for k, s in enumerate(problem.instances) if s.robot == robot and s.module == per_robot
    )
    shared = sorted({s.module for s in problem.instances if not s.robot})

    def why(module: str, who: str | None) -> object:
        return explain_module(
            problem,
            x,
            True,
            module,
            robot=who,
            refused=lambda k: refusals(fleet, cat, problem.instances[k]),
        )

    row: Row = {
        "robots": robots,
        "genes": problem.n_instances,
        "nodes": problem.n_nodes,
        "build_s": _median(max(1, runs // 2), lambda: build_problem(fleet, cat)),
        "refusals_s": _median(runs, lambda: refusals(fleet, cat, problem.instances[i])),
        "why_robot_s": _median(runs, lambda: why(per_robot, robot)),
    }
    if shared:
        row["why_shared_s"] = _median(runs, lambda: why(shared[0], None))
        row["shared"] = shared[0]
    return row
