"""Re-planning benchmark (``fogfleet bench replan``, ``make bench-replan``): a change to a
running fleet planned in full vs incrementally (``incremental.replan``).

Per size, the synthetic warehouse (``scheduling.synthetic_fleet``: n robots x 8 modules on
ceil(0.4 n) edge nodes, the proportions ``make bench-scale`` uses) is planned once by NSGA-II
with the operator's default settings; that plan runs. Then two changes, each re-planned both
ways and passed through the migration-margin rule (``stickiness.keep_running``) as the
operator does:

- *robot joins*: one more robot in the fleet (its 8 instances are new);
- *edge fails*: the edge node hosting the fewest instances becomes NotReady.

Columns: seconds (the incremental one a median of ``runs``, and its first run, which pays for
first-touching the new problem's arrays), running instances moved by the
deployed result, the deployed plan's predicted miss rate, and for the incremental re-plan the
instances it freed or why the operator would plan in full instead.
"""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

import numpy as np

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.incremental import changed_instances, replan
from fogfleet.scheduling.objectives import objective_values
from fogfleet.scheduling.solver import plan
from fogfleet.scheduling.stickiness import keep_running, mask_unavailable

__all__ = ["EDGES_PER_ROBOT", "replan_rows"]

EDGES_PER_ROBOT = 0.4  # as e2e/bench/scale.py
Row = dict[str, Any]


def _deployed(
    problem: Problem, x: np.ndarray, settings: SchedulerSettings, before: np.ndarray
) -> tuple[int, float]:
    """Instances the deployed result runs elsewhere than ``before`` (the placement before the
    change, -1 for new instances), and its predicted miss rate."""
    kept = keep_running(problem, x, settings)
    moved = int(np.sum((before >= 0) & (kept.placement != before)))
    miss = objective_values(problem, kept.placement, True, ["missRate"])["missRate"]
    return moved, miss


def _compare(
    change: str,
    old: Problem,
    new: Problem,
    before: np.ndarray,
    reference: float,
    settings: SchedulerSettings,
    runs: int,
) -> Row:
    row: Row = {"change": change, "genes": new.n_instances, "nodes": new.n_nodes}
    t0 = time.perf_counter()
    full = plan(new, settings)
    row["full_s"] = round(time.perf_counter() - t0, 2)
    row["full_moved"], miss = _deployed(new, full.placement, settings, before)
    row["full_missRate"] = round(miss, 5)
    changed = changed_instances(old, new)
    times, out = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = replan(new, settings, changed=changed, reference=reference)
        times.append(time.perf_counter() - t0)
    assert out is not None
    row["incr_s"] = round(statistics.median(times), 3)
    row["incr_first_s"] = round(times[0], 3)
    if out.schedule is None:
        row["incr_result"] = f"full plan: {out.reason}"
        return row
    row["incr_moved"], miss = _deployed(new, out.schedule.placement, settings, before)
    row["incr_missRate"] = round(miss, 5)
    row["incr_result"] = f"{out.affected} affected + {out.freed - out.affected} neighbours free"
    return row


def replan_rows(
    sizes: tuple[int, ...] = (100, 300, 1000), runs: int = 3, seed: int = 1
) -> list[Row]:
    """One row per (size, change); see the module docstring."""
    settings = SchedulerSettings(seed=seed)
    rows: list[Row] = []
    for robots in sizes:
        edges = max(2, math.ceil(EDGES_PER_ROBOT * robots))
        cat, fleet = synthetic_fleet(robots + 1, edges, seed)
        spec = fleet.spec.model_copy(update={"robots": fleet.spec.robots[:robots]})
        before = fleet.model_copy(update={"spec": spec})
        t0 = time.perf_counter()
        p0 = build_problem(before, cat)
        build_s = time.perf_counter() - t0
        first = plan(p0, settings)
        current = {
            (inst.robot, inst.module, inst.replica): p0.nodes[j].node_name
            for inst, j in zip(p0.instances, first.placement, strict=True)
        }
        reference = first.objectives["missRate"]
        head: Row = {
            "robots": robots,
            "build_s": round(build_s, 2),
            "first_plan_s": round(first.duration_seconds, 2),
        }
        joined = build_problem(fleet, cat, current)
        rows.append(
            head | _compare("robot joins", p0, joined, joined.current, reference, settings, runs)
        )
        running = build_problem(before, cat, current)
        count = np.bincount(first.placement[first.placement >= 0], minlength=running.n_nodes)
        edge = min(
            (j for j in range(running.n_nodes) if running.tier[j] == 1 and count[j] > 0),
            key=lambda j: (count[j], j),
        )
        failed, _ = mask_unavailable(running, {edge: "NotReady"})
        row = _compare("edge fails", p0, failed, running.current, reference, settings, runs)
        rows.append(head | row)
    return rows
