"""A RobotFleet's status as its model (Kubernetes API conventions), from the placement actually
deployed and what the cluster shows: conditions keyed by type with CamelCase reasons and
messages a person can act on, the placement table, the deployed plan's objective values; and
the Events of a new plan. Pure: the status step (``status_step``) compares and writes.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any

import numpy as np

from fogfleet.api.v1alpha1.objectives import ObjectiveName
from fogfleet.api.v1alpha1.placement import PLACEMENT_LIST_LIMIT, CompactPlacement
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, RobotFleetStatus
from fogfleet.controllers.measure.drift_report import DriftReport
from fogfleet.controllers.measure.links import LinkReport
from fogfleet.controllers.state import Rendered
from fogfleet.controllers.status import (
    Rollout,
    complete,
    condition,
    finite,
    merge_conditions,
    miss_fields,
    set_conditions,
    split_text,
    wire,
    wire_keys,
)
from fogfleet.domain.dnnpairs import planned_choice
from fogfleet.domain.miss_rates import format_miss_rate
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import format_cpu, identity_of
from fogfleet.scheduling.decision import Decision
from fogfleet.scheduling.explain.shortfall import degraded_message
from fogfleet.scheduling.fallback import disconnected
from fogfleet.scheduling.objectives import objective_values

__all__ = [
    "FLEET_STATUS_KEYS",
    "by_module",
    "fleet_status",
    "held_status",
    "placement_entries",
    "plan_events",
    "running_wire",
]

log = logging.getLogger(__name__)
FLEET_STATUS_KEYS = wire_keys(RobotFleetStatus)
Obj = dict[str, Any]


def placement_entries(
    problem: Problem, desired: list[Obj], roll: Rollout, cached: Decision | None, baseline: bool
) -> list[Obj]:
    """Where each rendered instance runs: the plan's node, or (k8s-default) the node
    kube-scheduler bound its pod to, and a split network's action there and why; an instance
    not placed yet is left out. (A split network's head Deployment has no identity: its tail's
    entry stands for it.)"""
    placement: list[Obj] = []
    index = _instance_index(problem)
    alloc = problem.nominal if baseline else problem.limits
    for dep in desired:
        ident = identity_of(dep)
        i = index.get(ident, -1) if ident else -1
        if baseline:
            node = roll.bound.get(dep["metadata"]["name"])
            if node is None:
                continue
            try:
                j = problem.node_index(node)
            except KeyError:
                continue
        else:
            if cached is None or i < 0:
                continue
            j = int(cached.placement[i])
        nd = problem.nodes[j]
        entry: Obj = {
            "robot": ident[0] if ident else "",
            "module": ident[1] if ident else "",
            "node": nd.name,
            "tier": nd.tier.value,
            "cpu": format_cpu(float(alloc.cpu_request[i, j])),
        }
        if ident and not ident[0]:
            entry["replica"] = ident[2]
        choice = None if baseline or i < 0 else planned_choice(problem, i, j)
        if choice is not None:
            entry["split"] = {"action": choice.action.name, "reason": choice.reason}
        placement.append(entry)
    return placement


def _instance_index(problem: Problem) -> dict[tuple[str, str, int], int]:
    """(robot, module, replica) -> the instance's row, as placement entries name it."""
    return {(inst.robot, inst.module, inst.replica): i for i, inst in enumerate(problem.instances)}


def by_module(placement: list[Obj]) -> list[Obj]:
    """``status.placementByModule``: per module, its instances per tier."""
    counts: dict[str, Counter[str]] = {}
    for entry in placement:
        counts.setdefault(str(entry["module"]), Counter())[str(entry["tier"])] += 1
    return [
        {"module": m, **{t: c[t] for t in ("robot", "edge", "cloud")}}
        for m, c in sorted(counts.items())
    ]


def fleet_status(
    fleet: RobotFleet,
    rendered: Rendered,
    placement: list[Obj],
    roll: Rollout,
    generation: int | None,
    old: Obj,
    links: LinkReport | None = None,
    drift: DriftReport | None = None,
    shared: list[Obj] | None = None,
    monitored: Obj | None = None,
    replan_failed: tuple[str, str] | None = None,
) -> RobotFleetStatus:
    """The status of a fleet whose instances stand where ``placement`` (placement_entries)
    says: the per-instance list up to PLACEMENT_LIST_LIMIT entries, its compact form above.
    ``monitored``: the operator's Monitored condition (``monitoring.Monitoring``);
    ``replan_failed``: (reason,
    message) of a re-plan that failed while the fleet runs ``rendered``, its last plan: Ready
    and Scheduled say it, Degraded and the rest still describe what runs."""
    problem, plan = rendered.problem, rendered.plan
    tiers = Counter(str(entry["tier"]) for entry in placement)
    if replan_failed is not None:
        reason, message = replan_failed
        ready_scheduled = [
            condition(t, False, reason, message, generation) for t in ("Ready", "Scheduled")
        ]
    else:
        ready_scheduled = [
            _ready(rendered, roll, generation),
            _scheduled(rendered, placement, generation),
        ]
    conds = [
        *ready_scheduled,
        _degraded(rendered, roll, links, generation),
    ]
    if drift is not None and drift.condition is not None:
        conds.append(condition("Drift", *drift.condition, generation))
    if monitored is not None:
        conds.append(monitored)
    parts: Obj = {
        "observed_generation": generation,
        "conditions": merge_conditions(old.get("conditions") or [], conds),
        "scheduler": fleet.spec.scheduler.algorithm.value,
        "placement": placement if len(placement) <= PLACEMENT_LIST_LIMIT else [],
        "placement_compact": (
            CompactPlacement.of(placement) if len(placement) > PLACEMENT_LIST_LIMIT else None
        ),
        "placement_by_module": by_module(placement),
        "modules_placed": len(placement),
        "modules_total": problem.n_instances,
        "split": split_text(tiers),
    }
    if plan is not None and problem.fallback_rows.size and not rendered.baseline:
        parts["fallbacks"] = _fallbacks(problem, plan.placement, links)
    elif old.get("fallbacks"):
        parts["fallbacks"] = []  # a merge patch would otherwise keep the stale list
    if links is not None and links.entries:
        parts["links"] = links.entries
    elif old.get("links"):
        parts["links"] = []
    if drift is not None and drift.entries:
        parts["measured"] = drift.entries
    elif old.get("measured"):
        parts["measured"] = []
    parts.update(_measured_miss(drift.measured_miss_rate if drift is not None else None))
    if shared:
        parts["shared_nodes"] = shared
    elif old.get("sharedNodes"):
        parts["shared_nodes"] = []
    parts.update(_plan_figures(rendered, placement))
    return RobotFleetStatus(**parts)


def _ready(rendered: Rendered, roll: Rollout, generation: int | None) -> Obj:
    desired, stranded = rendered.desired, rendered.stranded
    waiting = [*roll.waiting, *roll.moving]
    if not waiting and not stranded:
        message = f"All {len(desired)} modules run where planned"
        return condition("Ready", True, "AllModulesRunning", message, generation)
    if stranded:
        stuck = "; ".join(rendered.problem.reasons[i] for i in sorted(stranded))
        return condition("Ready", False, "NodeUnavailable", stuck, generation)
    message = (
        f"Waiting for {len(waiting)} of {len(desired)} modules to run where "
        f"planned: {', '.join(sorted(waiting)[:10])}"
    )
    return condition("Ready", False, "RollingOut", message, generation)


def _scheduled(rendered: Rendered, placement: list[Obj], generation: int | None) -> Obj:
    desired, total = rendered.desired, rendered.problem.n_instances
    if rendered.baseline:
        return condition(
            "Scheduled",
            len(placement) == len(desired),
            "KubeScheduler",
            f"kube-scheduler bound {len(placement)} of {len(desired)} modules",
            generation,
        )
    message = f"Planned {total - len(rendered.stranded)} of {total} modules"
    return condition("Scheduled", True, "Planned", message, generation)


def _degraded(
    rendered: Rendered, roll: Rollout, links: LinkReport | None, generation: int | None
) -> Obj:
    problem, stranded = rendered.problem, rendered.stranded
    link_degraded = links.degraded if links is not None else None
    if roll.moving or stranded or link_degraded:
        stuck = [problem.reasons[i] for i in sorted(stranded)]
        msg = f"{len(roll.moving)} module(s) moving to their new node" if roll.moving else ""
        msg = "; ".join(x for x in [link_degraded[1] if link_degraded else "", msg, *stuck] if x)
        reason = (
            "NodeUnavailable" if stranded else (link_degraded[0] if link_degraded else "Migrating")
        )
        return condition("Degraded", True, reason, msg, generation)
    if problem.degraded and rendered.plan is not None:
        message = _with_room(degraded_message(problem, rendered.plan.placement), rendered.room)
        return condition("Degraded", True, "ShortOfCapacity", message, generation)
    message = "Every module is where it was planned"
    return condition("Degraded", False, "AsPlanned", message, generation)


def _fallbacks(problem: Problem, placement: np.ndarray, links: LinkReport | None) -> list[Obj]:
    """Per robot, what a lost link costs it and (links monitored) what its standbys did."""
    out: list[Obj] = []
    for cut in disconnected(problem, placement):
        entry: Obj = {
            "robot": cut.robot,
            "reservedCpu": format_cpu(cut.reserved_cpu),
            "standbys": list(cut.standbys),
            "stopped": list(cut.stopped),
            "predictedMissRate": finite(cut.miss_rate),
        }
        took = links.takeovers_of(cut.robot, list(cut.standbys)) if links is not None else None
        if took is not None:
            entry["takeovers"] = took
        out.append(entry)
    return out


def _plan_figures(rendered: Rendered, placement: list[Obj]) -> Obj:
    """The deployed plan's figures; a k8s-default fleet's objectives once every module is
    bound (evaluated where kube-scheduler put them)."""
    plan, problem = rendered.plan, rendered.problem
    if plan is not None:
        objectives = plan.objectives
        return {
            "objectives": [
                {"name": k, "value": finite(v)}
                for k, v in objectives.items()
                if finite(v) is not None
            ],
            **_miss(objectives.get(ObjectiveName.MISS_RATE)),
            "planning_millis": round(plan.schedule.duration_seconds * 1000),
            "plan_gap": _gap(plan),
            "choice_reason": plan.choice_reason,
            "migrations": plan.migrations,
            "last_plan_time": plan.planned_at,
        }
    if not (rendered.baseline and placement and len(placement) == len(rendered.desired)):
        return {}
    x = np.full(problem.n_instances, -1, dtype=np.int64)
    index = _instance_index(problem)
    for entry in placement:
        key = (str(entry["robot"]), str(entry["module"]), int(entry.get("replica", 0)))
        x[index[key]] = problem.node_index(entry["node"])
    names = [ObjectiveName.MISS_RATE, ObjectiveName.MISSED_CYCLES]
    values = objective_values(problem, x, False, [str(n) for n in names])
    return {
        "objectives": [{"name": k, "value": finite(v)} for k, v in values.items()],
        **_miss(values.get(ObjectiveName.MISS_RATE)),
    }


def _gap(plan: Decision) -> Obj | None:
    """``status.planGap`` of the deployed plan (``scheduling.gap``)."""
    gap = plan.gap
    if gap is None or not np.isfinite(gap.deployed_percent):
        return None
    return {
        "percent": round(gap.percent, 2),
        "value": round(gap.value, 6),
        "bound": round(gap.bound, 6),
        "bound_kind": gap.kind,
        "deployed_percent": round(gap.deployed_percent, 2),
        "deployed_value": round(gap.deployed, 6),
        "time_budget_reached": plan.schedule.time_budget_reached,
    }


def _miss(rate: float | None) -> Obj:
    """The plan's predicted miss rate, as a fraction and as people read it (MISS column)."""
    value, text = miss_fields(rate)
    return {"predicted_miss_rate": value, "predicted_miss": text}


def _measured_miss(rate: float | None) -> Obj:
    """The fleet's measured miss rate beside the predicted one (MEASURED column); absent,
    never 0, while nothing was measured."""
    value, text = miss_fields(rate)
    return {"measured_miss_rate": value, "measured_miss": text}


def held_status(generation: int | None, old: Obj, conditions: list[Obj], keep: str = "") -> Obj:
    """The status of a fleet whose plan is held (paused, waiting for profiles, failed): its
    new conditions merged into the old ones, the rest as it was. ``keep``: "others" keeps
    every other old condition after them; "Degraded" keeps that one."""
    kept = (lambda _type: True) if keep == "others" else (lambda type_: type_ == keep)
    status = RobotFleetStatus(
        observed_generation=generation,
        conditions=set_conditions(old.get("conditions"), conditions, kept),
    )
    return {**old, **wire(status)}


def running_wire(status: RobotFleetStatus) -> Obj:
    """A full status as written: every field the reconcile owns, absent ones as None, so the
    merge patch removes a field it stopped writing."""
    return complete(wire(status), FLEET_STATUS_KEYS)


def _gap_text(cached: Decision) -> str:
    """The Planned Event's words on the plan's gap and the time budget."""
    cut = cached.schedule.budget_cut
    budget = f"; the time budget cut the {', the '.join(cut)}" if cut else ""
    gap = cached.gap
    return f"; {gap.describe()}{budget}" if gap is not None else budget


def _with_room(message: str, room: str) -> str:
    """A degradation with who else holds how many cores on the fleet's nodes."""
    return f"{message}; {room}" if room else message


def plan_events(problem: Problem, cached: Decision, room: str = "") -> list[tuple[str, str, str]]:
    """The Events of a decision made now: Planned, ShortOfCapacity, Migrated; ``room``: who
    else holds how many cores on the fleet's nodes (``snapshot.room_note``)."""
    p = cached.placement
    split = Counter(problem.nodes[j].tier.value for j in p if j >= 0)
    miss = cached.objectives.get(ObjectiveName.MISS_RATE)
    miss_txt = (
        f"; predicted miss rate {format_miss_rate(miss)}"
        if miss is not None and np.isfinite(miss)
        else ""
    )
    events = [
        (
            "Normal",
            "Planned",
            f"Planned {int((p >= 0).sum())} modules ({split['robot']} on board, "
            f"{split['edge']} edge, {split['cloud']} cloud) with "
            f"{cached.schedule.scheduler} in "
            f"{cached.schedule.duration_seconds * 1000:.0f} ms{miss_txt}{_gap_text(cached)}",
        )
    ]
    if problem.degraded:
        message = _with_room(degraded_message(problem, cached.placement), room)
        events.append(("Warning", "ShortOfCapacity", message))
    if cached.moves:
        moved = f"Moved {len(cached.moves)} running modules: {', '.join(cached.moves[:10])}"
        events.append(("Normal", "Migrated", moved))
    return events
