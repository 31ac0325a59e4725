"""The plan step: the fleet's planning problem (its unavailable nodes masked), and its decision:
from its state while the planning inputs are unchanged, else from
``scheduling.decision.decide`` (which plans, checks and keeps what runs).

Same inputs, same failure: an infeasible fleet is not planned again until they change.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fogfleet.api.v1alpha1.base import format_millicores
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.observe import (
    FleetInputs,
    Parsed,
    fleet_snapshot,
    record_references,
)
from fogfleet.controllers.state import FleetState, Rendered
from fogfleet.domain.problem import Problem
from fogfleet.domain.tenancy import Held, claims_of
from fogfleet.errors import Infeasible
from fogfleet.scheduling.decision import Decision, decide, fingerprint, with_defaults
from fogfleet.snapshot import FleetSnapshot, build, room_note

__all__ = ["Planned", "plan_fleet", "plan_step"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


def plan_fleet(
    deps: Deps,
    state: FleetState,
    problem: Problem,
    fleet: RobotFleet,
    before: np.ndarray,
    previous: Problem | None = None,
) -> tuple[Decision, bool]:
    """The fleet's decision and whether it was made now. ``previous`` is the last full pass's
    problem (it has the cached decision's inputs), so only what changed is re-planned."""
    settings = with_defaults(fleet.spec.scheduler, deps.scheduler_defaults)
    fp = fingerprint(problem, settings)
    if state.plan is not None and state.plan.fingerprint == fp:
        return state.plan, False
    if state.failure is not None and state.failure[0] == fp:
        raise state.failure[1]  # same inputs, same failure: do not run the GA again
    name = fleet.metadata.name
    try:
        decision = decide(
            deps.planner,
            problem,
            settings,
            fleet=name,
            fp=fp,
            before=before,
            last=state.plan,
            last_problem=previous,
        )
    except Infeasible as err:
        state.failure = (fp, err)
        raise
    state.failure = None
    state.plan = decision
    schedule = decision.schedule
    deps.metrics.observe_plan(
        name, schedule.scheduler, decision.seconds, decision.objectives, schedule.degraded_instances
    )
    deps.metrics.count_migrations(name, decision.migrations)
    if decision.why_full:
        log.info("RobotFleet %s/%s: planned the whole fleet: %s", *state.key, decision.why_full)
    # wall time against this thread's CPU time: what the planner waited for (the GIL, the
    # cores) beside what it computed
    log.info(
        "Planned RobotFleet %s/%s%s in %.0f ms (%.0f ms of CPU; %d migrations)",
        *state.key,
        " incrementally" if decision.incremental else "",
        decision.seconds * 1e3,
        decision.cpu_seconds * 1e3,
        decision.migrations,
    )
    return decision, True


@dataclass(frozen=True)
class Planned:
    """The plan step's result: the problem as planned and the decision deployed."""

    problem: Problem  # with a degraded plan's CPU amounts
    stranded: frozenset[int]  # instances whose node is unavailable: left where they are
    decision: Decision | None  # None: kube-scheduler places (k8s-default)
    planned: bool  # decided now (else the cached decision)
    snapshot: FleetSnapshot  # what it was planned from

    @property
    def baseline(self) -> bool:
        return self.decision is None


def plan_step(
    deps: Deps, state: FleetState, inputs: FleetInputs, parsed: Parsed, last: Rendered | None
) -> Planned:
    """Build the fleet's planning problem, mask unavailable nodes and decide."""
    fleet = inputs.fleet
    snapshot = fleet_snapshot(inputs, parsed, _recovered(inputs, last))
    built = build(snapshot)
    record_references(
        state,
        fleet,
        parsed.wanted,
        {n.name for n in built.built.nodes},
        {n.node_name for n in built.built.nodes},
    )
    problem, stranded, before = built.problem, built.stranded, built.before
    never = {i: why for i, why in problem.reasons.items() if i not in stranded}
    if never:
        why = "; ".join(never.values())
        err = Infeasible(f"RobotFleet/{fleet.metadata.name}", "spec.modules", why)
        raise _naming_the_others(err, problem, inputs.held)
    if fleet.spec.scheduler.algorithm is SchedulerName.K8S_DEFAULT:
        state.claims, state.shared = {}, []  # its pods hold what they request (tenancy)
        return Planned(problem, frozenset(stranded), None, False, snapshot)
    previous = last.problem if last is not None else None
    try:
        decision, planned = plan_fleet(deps, state, problem, fleet, before, previous)
    except Infeasible as err:
        state.claims, state.shared = {}, []
        raise _naming_the_others(err, problem, inputs.held) from None
    problem = problem.with_levels(decision.schedule.levels)  # a degraded plan's CPU amounts
    with_limits = decision.schedule.with_limits
    state.claims = claims_of(problem, decision.placement, with_limits)
    state.shared = shared_nodes(problem, inputs.held, state.claims)
    return Planned(problem, frozenset(stranded), decision, planned, snapshot)


def shared_nodes(
    problem: Problem, held: Mapping[str, Held], claims: Mapping[str, tuple[float, float]]
) -> list[Obj]:
    """``status.sharedNodes``: the fleet's nodes others hold part of, and what is left."""
    out: list[Obj] = []
    for j, node in enumerate(problem.nodes):
        h = held.get(node.node_name)
        if h is None or h.cpu <= 0:
            continue
        left = float(problem.capacity[j, 0]) - claims.get(node.node_name, (0.0, 0.0))[0]
        out.append(
            {
                "node": node.node_name,
                "heldCpu": format_millicores(h.cpu),
                "leftCpu": format_millicores(max(left, 0.0)),
                "heldBy": list(h.holders),
            }
        )
    return out


def _naming_the_others(err: Infeasible, problem: Problem, held: Mapping[str, Held]) -> Infeasible:
    """An infeasible plan on nodes others hold part of says who holds how many cores there,
    and what the fleet needs against what they leave it (``snapshot.room_note``)."""
    room = room_note(problem, held)
    if not room:
        return err
    return Infeasible(err.obj, err.field, f"{err.message}; {room}")


def _recovered(inputs: FleetInputs, last: Rendered | None) -> frozenset[str]:
    """The robots whose link is planned as declared again after a bad spell: their modules go
    where the plan puts them, not where the bad link had them moved (linkhealth)."""
    recovered = set(last.measured) - set(inputs.measured) if last is not None else set()
    if recovered:
        log.info(
            "RobotFleet %s/%s: %s planned with the declared link again",
            *inputs.obj.key,
            ", ".join(sorted(recovered)),
        )
    return frozenset(recovered)
