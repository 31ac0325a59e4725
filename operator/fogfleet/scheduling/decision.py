"""Which plan a fleet gets: plan (or re-plan what changed), check it, keep what runs.

``decide`` is the one place that turns a planning problem into the placement the operator
deploys:

1. an incremental re-plan of only what changed since the last decision (NSGA-II fleets planned
   before and not degraded; ``incremental.replan``), else a whole-fleet plan (``solver.plan``);
   a first decision for a fleet that already runs (a new leader after a failover, a restarted
   operator: no last decision in memory) keeps what runs: the incremental re-plan around the
   placement found in the cluster is deployed when its first objective is within the
   migration margin of the whole-fleet plan's (``_keep_what_runs``);
2. the plan must place every placeable instance and hold (F1-F3 constraints; paper IV-A),
   else ``Infeasible`` explains it by node and resource;
3. the migration-margin rule keeps running modules where they are unless the new plan is
   better by the margin, and by twice it to return one to the node it was last moved off
   (``stickiness.keep_running``; ``Decision.left`` remembers those nodes); where what runs
   no longer fits (a learnt profile asks for more CPU), it is held in place down the
   degradation ladders unless the new plan beats that by the margin (``stickiness.hold``);
4. the objectives reported are those of the placement deployed, not of the solver's proposal.

The controller keeps the returned ``Decision`` by fingerprint and recomputes nothing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import time
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.robotfleet import SchedulerName, SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible

from . import stickiness
from .explain.shortfall import infeasible_message
from .gap import PlanGap, plan_gap
from .incremental import Replan, changed_instances, replan
from .objectives import feasible, objective_values
from .schedule import Schedule
from .solver import exact_weights, plan

__all__ = ["CorePlanner", "Decision", "Planner", "decide", "fingerprint", "with_defaults"]

log = logging.getLogger(__name__)


class Planner(Protocol):
    """The solver, as a decision uses it (tests count or steer its calls)."""

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule: ...

    def replan(
        self,
        problem: Problem,
        settings: SchedulerSettings,
        changed: Collection[int],
        reference: float | None,
    ) -> Replan:
        """Re-plan only what a small change affected (``incremental.replan``); a Replan
        without a schedule asks for ``plan``."""
        ...


class CorePlanner:
    """The Planner over :func:`solver.plan` and :func:`incremental.replan`."""

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule:
        return plan(problem, settings)

    def replan(
        self,
        problem: Problem,
        settings: SchedulerSettings,
        changed: Collection[int],
        reference: float | None,
    ) -> Replan:
        return replan(problem, settings, changed=changed, reference=reference)


@dataclass(frozen=True)
class Decision:
    """The plan deployed for one set of planning inputs (``fingerprint``)."""

    fingerprint: str
    schedule: Schedule
    placement: NDArray[np.int64]  # what was chosen (after the migration-margin rule)
    plan_id: str
    migrations: int
    choice_reason: str
    planned_at: str
    moves: tuple[str, ...] = ()  # "robot-1/module edge-1->edge-2" for the Migrated Event
    objectives: dict[str, float] = field(default_factory=dict)
    """The objectives of ``placement`` (the plan deployed), not of the solver's proposal."""
    incremental: bool = False  # re-planned only what changed
    why_full: str = ""  # why a fleet planned before was planned in full ("" for a first plan)
    seconds: float = 0.0  # wall time of the planning
    cpu_seconds: float = 0.0  # this thread's CPU time of it (beside the wall: what it waited)
    left: dict[str, str] = field(default_factory=dict)
    """Instance label -> the node the migration-margin rule last moved it off (hysteresis:
    a return there needs twice the margin). Kept with the decision, in memory: after a restart
    the first re-plan has none."""
    gap: PlanGap | None = None
    """The deployed plan's S against a lower bound on every plan's S (``_gap``)."""


def with_defaults(given: SchedulerSettings, defaults: Mapping[str, int]) -> SchedulerSettings:
    """The fleet's scheduler settings, with operator-wide defaults for the fields it leaves
    out (FOGFLEET_SCHEDULER_*)."""
    missing = {k: v for k, v in defaults.items() if k not in given.model_fields_set}
    return given.model_copy(update=missing) if missing else given


def fingerprint(problem: Problem, settings: SchedulerSettings) -> str:
    """The planning inputs' fingerprint: same fingerprint, same decision."""
    return stickiness.fingerprint(problem, settings)


def decide(
    planner: Planner,
    problem: Problem,
    settings: SchedulerSettings,
    *,
    fleet: str,
    fp: str,
    before: NDArray[np.int64],
    last: Decision | None = None,
    last_problem: Problem | None = None,
) -> Decision:
    """The placement to deploy (see the module docstring). ``before`` is where instances
    run now (-1: nowhere); ``last``/``last_problem`` the previous decision and the problem it
    was made for (then only what changed is re-planned). Raises ``Infeasible`` naming
    ``RobotFleet/<fleet>``."""
    t0, cpu0 = time.perf_counter(), time.thread_time()
    holdable = _holdable(problem, last, last_problem)
    schedule, why_full = _incremental(planner, problem, settings, last, last_problem)
    incremental = schedule is not None
    if schedule is None:
        schedule = planner.plan(problem, settings)
        if last is None:
            kept = _keep_what_runs(planner, problem, settings, schedule)
            incremental = kept is not None
            schedule = kept or schedule
    seconds, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
    placement = np.asarray(schedule.placement, dtype=np.int64)
    # a degraded plan's CPU amounts, feasibility and figures hold for the degraded problem
    problem = problem.with_levels(schedule.levels)
    with_limits = schedule.with_limits  # False: onboard, planned for the nominal allocation
    # instances with no node left (stranded: their node is down) stay unplaced; every other
    # one must be placed and the plan must hold
    placeable = problem.allowed.any(axis=1)
    unplaced = bool((placement[placeable] < 0).any())
    if unplaced or not feasible(problem, placement, with_limits):
        message = infeasible_message(problem, placement, schedule.reasons)
        raise Infeasible(f"RobotFleet/{fleet}", "spec", message)
    left = _left_nodes(problem, last)
    stick = stickiness.keep_running(problem, placement, settings, with_limits, left, holdable)
    chosen = stick.placement
    if stick.levels is not None:  # held where it runs, with the rungs that fit it there
        schedule = dataclasses.replace(schedule, levels=stick.levels)
        problem = problem.with_levels(stick.levels)
    plan_id = hashlib.sha256(f"{fp}:{chosen.tobytes().hex()}".encode()).hexdigest()[:12]
    reason = schedule.choice_reason
    if stick.kept_current or stick.migrations:
        reason = f"{reason}; {stick.reason}" if reason else stick.reason
    moves = tuple(
        f"{problem.label(i)} {problem.nodes[before[i]].name}->{problem.nodes[chosen[i]].name}"
        for i in range(problem.n_instances)
        if before[i] >= 0 and chosen[i] >= 0 and chosen[i] != before[i]
    )
    objectives = (
        dict(schedule.objectives)
        if np.array_equal(chosen, placement) and stick.levels is None
        else objective_values(problem, chosen, with_limits, list(schedule.objectives))
    )
    return Decision(
        fp,
        schedule,
        chosen,
        plan_id,
        len(moves),
        reason,
        timestamp(),
        moves,
        objectives,
        incremental,
        why_full,
        seconds,
        cpu,
        _remember(problem, last, stick),
        _gap(problem, chosen, settings, schedule, incremental),
    )


# an incremental re-plan of a fleet with more (instance, node) pairs gets no gap: the robot
# bound takes ~1.5 s at 1000 robots (2.4 M pairs), the re-plan itself well under a second
GAP_INCREMENTAL_PAIRS = 250_000


def _gap(
    problem: Problem,
    chosen: NDArray[np.int64],
    settings: SchedulerSettings,
    schedule: Schedule,
    incremental: bool,
) -> PlanGap | None:
    """The deployed plan's gap (``gap.plan_gap``) under the weights the exact scheduler would
    minimise for the fleet; None for a degraded plan or one held below its rows (its CPU
    amounts are not the limits allocation's), a plan of the nominal allocation (onboard),
    and an incremental re-plan above ``GAP_INCREMENTAL_PAIRS``."""
    if not schedule.with_limits or schedule.degraded:
        return None
    if incremental and int(problem.allowed.sum()) > GAP_INCREMENTAL_PAIRS:
        return None
    w = exact_weights(problem, settings)
    try:
        return plan_gap(problem, chosen, w, schedule.pareto_placements, schedule.robot_bound)
    except Exception:  # a report: its bug must not keep a fleet from its plan
        log.exception("The plan's gap could not be computed (a bug: please report it)")
        return None


def _keep_what_runs(
    planner: Planner, problem: Problem, settings: SchedulerSettings, full: Schedule
) -> Schedule | None:
    """A first decision for a fleet whose instances already run (after a failover or a
    restart the operator has no last decision, only the placement in the cluster): the
    incremental re-plan around what runs (``incremental.replan``: what has no usable node or
    no longer fits is affected, with its neighbourhood), when its first objective is no worse
    than the whole-fleet plan ``full``'s by more than the migration margin; else None (deploy
    ``full``). Not for a degraded plan, whose CPU amounts are chosen for the whole fleet."""
    if not settings.incremental or SchedulerName(settings.algorithm) is not SchedulerName.NSGA2:
        return None
    if full.degraded or not bool((problem.current >= 0).any()):
        return None
    first = str(settings.objectives[0])
    result = planner.replan(problem, settings, (), full.objectives.get(first))
    if result.schedule is None:
        return None
    reason = f"kept what runs (no last decision in memory): {result.schedule.choice_reason}"
    return dataclasses.replace(result.schedule, choice_reason=reason)


def _holdable(
    problem: Problem, last: Decision | None, last_problem: Problem | None
) -> NDArray[np.bool_] | None:
    """(I,) the instances the migration-margin rule may hold in place below their row when what
    runs no longer fits (``stickiness.hold``): those whose own inputs changed since the last
    decision (``incremental.changed_instances``: a learnt profile, a new cycle time) and those
    the last decision already ran below it; None without a last decision."""
    if last is None or last_problem is None:
        return None
    out = np.zeros(problem.n_instances, dtype=bool)
    out[sorted(changed_instances(last_problem, problem))] = True
    levels = last.schedule.levels
    if levels is not None:
        where = {inst: k for k, inst in enumerate(last_problem.instances)}
        for i, inst in enumerate(problem.instances):
            k = where.get(inst)
            out[i] |= k is not None and k < len(levels) and bool(levels[k] > 0)
    return out


def _left_nodes(problem: Problem, last: Decision | None) -> NDArray[np.int64]:
    """(I,) the node index each instance was last moved off (``Decision.left``), -1: none."""
    index = {n.name: j for j, n in enumerate(problem.nodes)}
    before = last.left if last is not None else {}
    names = (before.get(problem.label(i), "") for i in range(problem.n_instances))
    return np.array([index.get(name, -1) for name in names], dtype=np.int64)


def _remember(
    problem: Problem, last: Decision | None, stick: stickiness.Stickiness
) -> dict[str, str]:
    """``Decision.left`` after this decision: the last one's, and the nodes the instances it
    moved ran on."""
    labels = {problem.label(i) for i in range(problem.n_instances)}
    left = {k: v for k, v in (last.left if last is not None else {}).items() if k in labels}
    for i in stick.migrations:
        left[problem.label(i)] = problem.nodes[int(problem.current[i])].name
    return left


def _incremental(
    planner: Planner,
    problem: Problem,
    settings: SchedulerSettings,
    last: Decision | None,
    last_problem: Problem | None,
) -> tuple[Schedule | None, str]:
    """The incremental re-plan of a fleet planned before by NSGA-II (not degraded: a degraded
    plan's CPU amounts are chosen for the whole fleet), or None and why the whole fleet is
    planned instead ("" for a first plan)."""
    if last is None or last_problem is None:
        return None, ""
    if not settings.incremental or SchedulerName(settings.algorithm) is not SchedulerName.NSGA2:
        return None, ""
    if last.schedule.degraded:
        return None, "the deployed plan is degraded"
    first = str(settings.objectives[0])
    result = planner.replan(
        problem, settings, changed_instances(last_problem, problem), last.objectives.get(first)
    )
    return result.schedule, result.reason
