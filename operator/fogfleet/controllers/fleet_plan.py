"""Plan a fleet: run the planner when the planning inputs changed (fingerprint cache), first
incrementally (only what the change affected) when the fleet was planned before, apply the
migration-margin rule to what runs, and explain an infeasible fleet by node and resource.
"""

from __future__ import annotations

import hashlib
import logging
import time

import numpy as np

from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName, SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible
from fogfleet.scheduling import stickiness
from fogfleet.scheduling.explain import infeasible_message
from fogfleet.scheduling.incremental import changed_instances
from fogfleet.scheduling.schedule import Schedule

from .deps import CachedPlan, Deps, FleetKey
from .status import now

__all__ = ["plan_fleet"]

log = logging.getLogger(__name__)


def plan_fleet(
    deps: Deps,
    key: FleetKey,
    problem: Problem,
    fleet: RobotFleet,
    before: np.ndarray,
    previous: Problem | None = None,
) -> tuple[CachedPlan, bool]:
    """The fleet's plan: the cached one while the planning inputs are unchanged, else an
    incremental re-plan against ``previous`` (the last full pass's problem, which has the
    cached plan's inputs: same fingerprint) or a whole-fleet plan."""
    given = fleet.spec.scheduler
    defaults = {k: v for k, v in deps.scheduler_defaults.items() if k not in given.model_fields_set}
    settings = given.model_copy(update=defaults) if defaults else given
    fp = stickiness.fingerprint(problem, settings)
    cached = deps.plans.get(key)
    if cached is not None and cached.fingerprint == fp:
        return cached, False
    failed = deps.failures.get(key)
    if failed is not None and failed[0] == fp:
        raise failed[1]  # same inputs, same failure: do not run the GA again
    t0, cpu0 = time.perf_counter(), time.thread_time()
    schedule, why_full = _incremental(deps, problem, settings, cached, previous)
    incremental = schedule is not None
    if schedule is None:
        if why_full:
            log.info("RobotFleet %s/%s: planning the whole fleet: %s", *key, why_full)
        schedule = deps.planner.plan(problem, settings)
    seconds, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
    placement = np.asarray(schedule.placement, dtype=np.int64)
    # a degraded plan's CPU amounts, feasibility and figures hold for the degraded problem
    problem = problem.with_levels(schedule.levels)
    with_limits = schedule.with_limits  # False: onboard, planned for the nominal allocation
    # instances with no node left (stranded: their node is down) stay unplaced; every other
    # one must be placed and the plan must hold
    placeable = problem.allowed.any(axis=1)
    unplaced = bool((placement[placeable] < 0).any())
    if unplaced or not stickiness.feasible(problem, placement, with_limits):
        err = Infeasible(
            f"RobotFleet/{key[1]}",
            "spec",
            infeasible_message(problem, placement, schedule.reasons),
        )
        deps.failures[key] = (fp, err)
        raise err
    deps.failures.pop(key, None)
    stick = stickiness.keep_running(problem, placement, settings, with_limits)
    plan_id = hashlib.sha256(f"{fp}:{stick.placement.tobytes().hex()}".encode()).hexdigest()[:12]
    reason = schedule.choice_reason
    if stick.kept_current or stick.migrations:
        reason = f"{reason}; {stick.reason}" if reason else stick.reason
    chosen = stick.placement
    moves = tuple(
        f"{problem.label(i)} {problem.nodes[before[i]].name}->{problem.nodes[chosen[i]].name}"
        for i in range(problem.n_instances)
        if before[i] >= 0 and chosen[i] >= 0 and chosen[i] != before[i]
    )
    # the migration-margin rule may keep what runs: report the deployed plan, not the proposal
    objectives = (
        dict(schedule.objectives)
        if np.array_equal(chosen, placement)
        else stickiness.objective_values(problem, chosen, with_limits, list(schedule.objectives))
    )
    cached = CachedPlan(fp, schedule, chosen, plan_id, len(moves), reason, now(), moves, objectives)
    deps.plans[key] = cached
    deps.metrics.observe_plan(
        key[1], schedule.scheduler, seconds, objectives, schedule.degraded_instances
    )
    deps.metrics.count_migrations(key[1], len(moves))
    # wall time against this thread's CPU time: what the planner waited for (the GIL, the
    # cores) beside what it computed
    log.info(
        "Planned RobotFleet %s/%s%s in %.0f ms (%.0f ms of CPU; %d migrations)",
        *key,
        " incrementally" if incremental else "",
        seconds * 1e3,
        cpu * 1e3,
        len(moves),
    )
    return cached, True


def _incremental(
    deps: Deps,
    problem: Problem,
    settings: SchedulerSettings,
    cached: CachedPlan | None,
    previous: Problem | None,
) -> tuple[Schedule | None, str]:
    """The incremental re-plan of a fleet planned before by NSGA-II (not degraded: a degraded
    plan's CPU amounts are chosen for the whole fleet), or None and why the whole fleet is
    planned instead ("" for a first plan)."""
    if cached is None or previous is None:
        return None, ""
    if not settings.incremental or SchedulerName(settings.algorithm) is not SchedulerName.NSGA2:
        return None, ""
    if cached.schedule.degraded:
        return None, "the deployed plan is degraded"
    first = str(settings.objectives[0])
    result = deps.planner.replan(
        problem,
        settings,
        changed_instances(previous, problem),
        cached.objectives.get(first),
    )
    return result.schedule, result.reason
