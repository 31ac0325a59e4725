"""A RobotFleet's status (Kubernetes API conventions) and Events, from the placement actually
deployed and what the cluster shows: conditions keyed by type with CamelCase reasons and
messages a person can act on, the placement table, the deployed plan's objective values.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any

import numpy as np

from fogfleet.api.v1alpha1.robotfleet import PLACEMENT_LIST_LIMIT, RobotFleet, RobotFleetStatus
from fogfleet.domain.problem import Problem
from fogfleet.errors import DanglingReference, Infeasible, InvalidSpec
from fogfleet.render.deployments import format_cpu, identity_of
from fogfleet.scheduling import stickiness
from fogfleet.scheduling.explain import degraded_message
from fogfleet.scheduling.fallback import disconnected

from .deps import CachedPlan, Deps, fleet_key
from .drift_report import DriftReport
from .links import LinkReport
from .status import (
    complete,
    condition,
    finite,
    merge_conditions,
    same_status,
    split_text,
    typed,
    wire_keys,
)

__all__ = [
    "FLEET_STATUS_KEYS",
    "by_module",
    "fleet_status",
    "placement_entries",
    "plan_events",
    "report_failure",
]

log = logging.getLogger(__name__)
FLEET_STATUS_KEYS = wire_keys(RobotFleetStatus)
Obj = dict[str, Any]


def placement_entries(
    problem: Problem, desired: list[Obj], roll: Any, cached: CachedPlan | None, baseline: bool
) -> list[Obj]:
    """Where each rendered instance runs: the plan's node, or (k8s-default) the node
    kube-scheduler bound its pod to; an instance not placed yet is left out."""
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
    problem: Problem,
    desired: list[Obj],
    placement: list[Obj],
    roll: Any,
    stranded: set[int],
    cached: CachedPlan | None,
    planned: bool,
    baseline: bool,
    generation: int | None,
    old: Obj,
    links: LinkReport | None = None,
    drift: DriftReport | None = None,
) -> Obj:
    """The status of a fleet whose instances stand where ``placement`` (placement_entries)
    says; the per-instance list only up to PLACEMENT_LIST_LIMIT entries."""
    tiers = Counter(str(entry["tier"]) for entry in placement)
    total = problem.n_instances
    stuck = [problem.reasons[i] for i in sorted(stranded)]
    waiting = [n for n in roll.waiting] + [n for n in roll.moving]
    ready = not waiting and not stranded
    if ready:
        ready_c = condition(
            "Ready",
            True,
            "AllModulesRunning",
            f"All {len(desired)} modules run where planned",
            generation,
        )
    elif stranded:
        ready_c = condition("Ready", False, "NodeUnavailable", "; ".join(stuck), generation)
    else:
        ready_c = condition(
            "Ready",
            False,
            "RollingOut",
            f"Waiting for {len(waiting)} of {len(desired)} modules to run where "
            f"planned: {', '.join(sorted(waiting)[:10])}",
            generation,
        )
    link_degraded = links.degraded if links is not None else None
    if roll.moving or stranded or link_degraded:
        msg = f"{len(roll.moving)} module(s) moving to their new node" if roll.moving else ""
        msg = "; ".join(x for x in [link_degraded[1] if link_degraded else "", msg, *stuck] if x)
        reason = (
            "NodeUnavailable" if stranded else (link_degraded[0] if link_degraded else "Migrating")
        )
        degraded = condition("Degraded", True, reason, msg, generation)
    elif problem.degraded and cached is not None:
        degraded = condition(
            "Degraded",
            True,
            "ShortOfCapacity",
            degraded_message(problem, cached.placement),
            generation,
        )
    else:
        degraded = condition(
            "Degraded", False, "AsPlanned", "Every module is where it was planned", generation
        )
    if baseline:
        sched = condition(
            "Scheduled",
            len(placement) == len(desired),
            "KubeScheduler",
            f"kube-scheduler bound {len(placement)} of {len(desired)} modules",
            generation,
        )
    else:
        sched = condition(
            "Scheduled",
            True,
            "Planned",
            f"Planned {total - len(stranded)} of {total} modules",
            generation,
        )
    conds = [ready_c, sched, degraded]
    if drift is not None and drift.condition is not None:
        conds.append(condition("Drift", *drift.condition, generation))
    status: Obj = {
        "observedGeneration": generation,
        "conditions": merge_conditions(old.get("conditions") or [], conds),
        "scheduler": fleet.spec.scheduler.algorithm.value,
        "placement": placement if len(placement) <= PLACEMENT_LIST_LIMIT else [],
        "placementByModule": by_module(placement),
        "modulesPlaced": len(placement),
        "modulesTotal": total,
        "split": split_text(tiers),
    }
    if cached is not None and problem.fallback_rows.size and not baseline:
        status["fallbacks"] = [
            {
                "robot": cut.robot,
                "reservedCpu": format_cpu(cut.reserved_cpu),
                "standbys": list(cut.standbys),
                "stopped": list(cut.stopped),
                "predictedMissRate": finite(cut.miss_rate),
            }
            for cut in disconnected(problem, cached.placement)
        ]
    elif old.get("fallbacks"):
        status["fallbacks"] = []  # a merge patch would otherwise keep the stale list
    if links is not None and links.entries:
        status["links"] = links.entries
    elif old.get("links"):
        status["links"] = []
    if drift is not None and drift.entries:
        status["measured"] = drift.entries
    elif old.get("measured"):
        status["measured"] = []
    if cached is not None:
        objectives = cached.objectives
        status.update(
            {
                "objectives": [
                    {"name": k, "value": finite(v)}
                    for k, v in objectives.items()
                    if finite(v) is not None
                ],
                "predictedMissRate": finite(objectives.get("missRate")),
                "planningMillis": round(cached.schedule.duration_seconds * 1000),
                "choiceReason": cached.choice_reason,
                "migrations": cached.migrations,
                "lastPlanTime": cached.planned_at,
            }
        )
    elif baseline and len(placement) == len(desired) and placement:
        x = np.full(problem.n_instances, -1, dtype=np.int64)
        index = _instance_index(problem)
        for entry in placement:
            key = (str(entry["robot"]), str(entry["module"]), int(entry.get("replica", 0)))
            x[index[key]] = problem.node_index(entry["node"])
        values = stickiness.objective_values(problem, x, False, ["missRate", "missedCycles"])
        status["objectives"] = [{"name": k, "value": finite(v)} for k, v in values.items()]
        status["predictedMissRate"] = finite(values.get("missRate"))
    return complete(typed(RobotFleetStatus, status), FLEET_STATUS_KEYS)


def plan_events(deps: Deps, body: Obj, problem: Problem, cached: CachedPlan) -> None:
    p = cached.placement
    split = Counter(problem.nodes[j].tier.value for j in p if j >= 0)
    miss = cached.objectives.get("missRate")
    miss_txt = (
        f"; predicted miss rate {miss * 100:.2f}%" if miss is not None and np.isfinite(miss) else ""
    )
    deps.kube.emit_event(
        body,
        "Normal",
        "Planned",
        f"Planned {int((p >= 0).sum())} modules ({split['robot']} on board, "
        f"{split['edge']} edge, {split['cloud']} cloud) with "
        f"{cached.schedule.scheduler} in "
        f"{cached.schedule.duration_seconds * 1000:.0f} ms{miss_txt}",
    )
    if problem.degraded:
        deps.kube.emit_event(
            body, "Warning", "ShortOfCapacity", degraded_message(problem, cached.placement)
        )
    if cached.moves:
        deps.kube.emit_event(
            body,
            "Normal",
            "Migrated",
            f"Moved {len(cached.moves)} running modules: {', '.join(cached.moves[:10])}",
        )


def report_failure(
    body: Obj, deps: Deps, old: Obj, generation: int | None, exc: InvalidSpec
) -> None:
    """Ready=False with the precise reason, one Event; nothing that runs is touched."""
    ns, name = fleet_key(body)
    deps.metrics.count_error(name, exc.reason)
    msg = str(exc)
    if isinstance(exc, DanglingReference):
        msg += " (create it, or fix the reference)"
    conds = [
        condition("Ready", False, exc.reason, msg, generation),
        condition("Scheduled", False, exc.reason, msg, generation),
    ]
    keep = [c for c in old.get("conditions") or [] if c.get("type") == "Degraded"]
    status = {
        **old,
        "observedGeneration": generation,
        "conditions": merge_conditions(old.get("conditions") or [], conds) + keep,
    }
    if not same_status(old, status):
        deps.kube.patch_fleet_status(ns, name, status)
        deps.kube.emit_event(
            body, "Warning", "PlanFailed" if isinstance(exc, Infeasible) else exc.reason, msg
        )
    log.warning("Failed to reconcile RobotFleet %s/%s: %s", ns, name, msg)
