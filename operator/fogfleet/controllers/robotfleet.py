"""The RobotFleet controller: one level-based ``reconcile(fleet, deps) -> Outcome``.

Create, update, resume, the drift timer and every debounced trigger (a module, ComputeNode or
Node changed; a Deployment moved) call the same function. It reads everything fresh, plans
only when the planning inputs changed (fingerprint cache), keeps running modules in place
unless the new plan is better by the migration margin, applies with server-side apply, prunes
stale Deployments, and writes the status in one patch. Invalid input (bad spec, dangling
reference, a fleet that cannot fit) touches nothing that runs: it sets ``Ready=False`` with the
reason, posts an Event and re-raises so the handler can map it.

Blocking (API calls, the GA): run it in a worker thread (``asyncio.to_thread``).
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.controllers.ros import apply_ros_wiring, is_ros_object
from fogfleet.domain.problem import Problem, build_problem
from fogfleet.errors import DanglingReference, Infeasible, InvalidSpec
from fogfleet.render.deployments import (
    ANNOTATION_SPEC_HASH,
    LABEL_FLEET,
    Owner,
    format_cpu,
    identity_of,
    label_value,
    render_fleet,
)

from . import planning
from .deps import CachedPlan, Deps, FleetKey
from .inputs import current_placement, gather
from .status import condition, finite, merge_conditions, now, rollout, same_status

__all__ = ["Outcome", "forget", "reconcile"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


@dataclass(frozen=True)
class Outcome:
    planned: bool = False
    applied: int = 0
    pruned: int = 0
    migrations: int = 0
    ready: bool = False
    requeue_after: float | None = None
    message: str = ""


def _key(body: Obj) -> FleetKey:
    meta = body.get("metadata") or {}
    return meta.get("namespace") or "default", meta["name"]


def forget(deps: Deps, key: FleetKey) -> None:
    """The fleet is gone: drop its cache and references (its Deployments go with it)."""
    deps.plans.pop(key, None)
    deps.failures.pop(key, None)
    deps.refs.forget(key)


def reconcile(body: Obj, deps: Deps) -> Outcome:
    """Bring the cluster to the fleet's desired state. See the module docstring."""
    key = _key(body)
    old_status: Obj = body.get("status") or {}
    generation = (body.get("metadata") or {}).get("generation")
    try:
        obj = parse_object({k: v for k, v in body.items() if k != "status"})
        assert isinstance(obj, RobotFleet)
        fleet = obj
        _record_references(deps, key, fleet)
        if fleet.spec.paused:
            return _paused(body, deps, old_status, generation)
        return _reconcile(body, fleet, deps, old_status, generation)
    except InvalidSpec as exc:
        _fail(body, deps, old_status, generation, exc)
        raise


def _record_references(deps: Deps, key: FleetKey, fleet: RobotFleet) -> None:
    names = set(fleet.spec.robots) | set(fleet.spec.nodes)
    selector = fleet.spec.robot_selector is not None or fleet.spec.node_selector is not None
    deps.refs.record(key, names, set(), {m.name for m in fleet.spec.modules}, selector)


def _reconcile(
    body: Obj, fleet: RobotFleet, deps: Deps, old_status: Obj, generation: int | None
) -> Outcome:
    key = _key(body)
    ns, name = key
    kube = deps.kube
    selector = {LABEL_FLEET: label_value(name)}
    deployments = [
        d for d in kube.list_deployments(ns, selector) if _owned(d, body) and not is_ros_object(d)
    ]
    raw_modules = kube.list_modules(ns)
    inputs = gather(fleet, kube.list_compute_nodes(), raw_modules, kube.list_nodes())
    _raise_broken_references(fleet, inputs.broken)
    problem = build_problem(
        fleet, inputs.catalog, current_placement(deployments), scaling_pools(raw_modules)
    )
    deps.refs.record(
        key,
        {n.name for n in problem.nodes},
        {n.node_name for n in problem.nodes},
        {m.name for m in fleet.spec.modules},
        fleet.spec.robot_selector is not None or fleet.spec.node_selector is not None,
    )
    unavailable = {
        j: inputs.unavailable[n.name]
        for j, n in enumerate(problem.nodes)
        if n.name in inputs.unavailable
    }
    before = problem.current
    problem, stranded = planning.mask_unavailable(problem, unavailable)
    never = {i: why for i, why in problem.reasons.items() if i not in stranded}
    if never:
        raise Infeasible(f"RobotFleet/{name}", "spec.modules", "; ".join(never.values()))
    modules = {
        m.metadata.name: m
        for m in inputs.catalog.modules.values()
        if (m.metadata.namespace or "default") == ns
    }
    owner = Owner(name, body["metadata"]["uid"]) if body["metadata"].get("uid") else None
    baseline = fleet.spec.scheduler.algorithm is SchedulerName.K8S_DEFAULT
    cached: CachedPlan | None = None
    planned = False
    if not baseline:
        cached, planned = _plan(deps, key, problem, fleet, before)
    # after planning: an infeasible fleet gets nothing applied, not even its discovery servers
    wiring = apply_ros_wiring(deps.kube, fleet, problem, owner, selector, modules.values())
    if baseline or cached is None:
        desired = render_fleet(problem, modules, None, baseline=True, owner=owner, wiring=wiring)
    else:
        desired = render_fleet(
            problem,
            modules,
            cached.placement,
            owner=owner,
            plan_id=cached.plan_id,
            wiring=wiring,
        )
    applied, pruned = _apply(deps, ns, desired, deployments, problem, stranded)
    if applied or pruned:
        deployments = [
            d
            for d in kube.list_deployments(ns, selector)
            if _owned(d, body) and not is_ros_object(d)
        ]
    pods = kube.list_pods(ns, selector)
    roll = rollout(desired, deployments, pods)
    status = _status(
        fleet, problem, desired, roll, stranded, cached, planned, baseline, generation, old_status
    )
    if not same_status(old_status, status):
        kube.patch_fleet_status(ns, name, status)
    if planned and cached is not None:
        _plan_events(deps, body, problem, cached)
    if applied or pruned:
        deps.metrics.count_apply(name, applied, pruned)
    ready = not roll.waiting and not roll.moving and not stranded
    return Outcome(
        planned=planned,
        applied=applied,
        pruned=pruned,
        migrations=cached.migrations if (cached and planned) else 0,
        ready=ready,
        requeue_after=None if ready else deps.requeue_seconds,
        message=status["conditions"][0]["message"],
    )


def scaling_pools(modules: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """The autoscaler's last decision per shared module: {module: {tier: replicas}}.

    Read from the SoftwareModules as the API server sends them (one namespace's): the
    catalog's modules are parsed without their status (``inputs.gather``), so they never
    carry ``status.scaling``. A status this operator did not write in this shape is ignored."""
    pools: dict[str, dict[str, int]] = {}
    for raw in modules:
        scaling = (raw.get("status") or {}).get("scaling")
        if not isinstance(scaling, Mapping):
            continue
        try:
            name = str(raw["metadata"]["name"])
            tiers = {str(p["tier"]): int(p["replicas"]) for p in scaling.get("pools") or []}
            pools[name] = tiers or {"any": int(scaling["desiredReplicas"])}
        except (KeyError, TypeError, ValueError):
            log.warning("Ignored an unreadable status.scaling: %s", scaling)
    return pools


def _owned(dep: Obj, fleet: Obj) -> bool:
    uid = (fleet.get("metadata") or {}).get("uid")
    refs = (dep.get("metadata") or {}).get("ownerReferences") or []
    return not uid or not refs or any(r.get("uid") == uid for r in refs)


def _raise_broken_references(fleet: RobotFleet, broken: dict[str, InvalidSpec]) -> None:
    wanted = [f"ComputeNode/{n}" for n in [*fleet.spec.robots, *fleet.spec.nodes]]
    wanted += [f"SoftwareModule/{m.name}" for m in fleet.spec.modules]
    for ref in wanted:
        if ref in broken:
            exc = broken[ref]
            raise InvalidSpec(
                f"RobotFleet/{fleet.metadata.name}",
                "spec",
                f"references {exc.obj}, which is invalid: {exc.field}: {exc.message}",
            )


def _plan(
    deps: Deps, key: FleetKey, problem: Problem, fleet: RobotFleet, before: np.ndarray
) -> tuple[CachedPlan, bool]:
    given = fleet.spec.scheduler
    defaults = {k: v for k, v in deps.scheduler_defaults.items() if k not in given.model_fields_set}
    settings = given.model_copy(update=defaults) if defaults else given
    fp = planning.fingerprint(problem, settings)
    cached = deps.plans.get(key)
    if cached is not None and cached.fingerprint == fp:
        return cached, False
    failed = deps.failures.get(key)
    if failed is not None and failed[0] == fp:
        raise failed[1]  # same inputs, same failure: do not run the GA again
    t0 = time.perf_counter()
    schedule = deps.planner.plan(problem, settings)
    seconds = time.perf_counter() - t0
    placement = np.asarray(schedule.placement, dtype=np.int64)
    if not schedule.feasible or not planning.feasible(problem, placement, True):
        err = Infeasible(
            f"RobotFleet/{key[1]}",
            "spec",
            _infeasible_message(problem, placement, schedule.reasons),
        )
        deps.failures[key] = (fp, err)
        raise err
    deps.failures.pop(key, None)
    stick = planning.keep_running(problem, placement, settings)
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
    cached = CachedPlan(fp, schedule, chosen, plan_id, len(moves), reason, now(), moves)
    deps.plans[key] = cached
    deps.metrics.observe_plan(key[1], schedule.scheduler, seconds, schedule.objectives)
    deps.metrics.count_migrations(key[1], len(moves))
    log.info(
        "Planned RobotFleet %s/%s in %.0f ms (%d migrations)",
        *key,
        seconds * 1e3,
        len(moves),
    )
    return cached, True


def _infeasible_message(problem: Problem, placement: np.ndarray, reasons: dict[int, str]) -> str:
    """Say what cannot fit where: single modules larger than every node they may use, then
    the constraints the best plan found still violates."""
    from fogfleet.scheduling.objectives import constraint_names, constraints

    parts: list[str] = []
    need = {"cpu": problem.limits.cpu_request, "memory": problem.memory, "gpu": problem.gpu}
    for i in range(problem.n_instances):
        nodes = np.flatnonzero(problem.allowed[i])
        for r, (name, demand) in enumerate(need.items()):
            d = demand[i, nodes] if demand.ndim == 2 else np.full(len(nodes), demand[i])
            if len(nodes) and np.all(d > problem.capacity[nodes, r] + 1e-9):
                biggest = int(nodes[np.argmax(problem.capacity[nodes, r])])
                parts.append(
                    f"{problem.label(i)} needs {_amount(name, float(d.min()))} {name} but "
                    f"the largest node it may use ({problem.nodes[biggest].name}) has "
                    f"{_amount(name, float(problem.capacity[biggest, r]))}"
                )
    if not parts:
        g = constraints(problem, placement[None, :], problem.limits)[0]
        names = constraint_names(problem)
        parts = [f"{n} over by {v * 100:.0f}%" for n, v in zip(names, g, strict=True) if v > 1e-9][
            :8
        ]
    head = "no placement fits the fleet's nodes"
    detail = "; ".join(parts[:8]) or "; ".join(reasons.values()) or "constraints violated"
    return f"{head}: {detail}"


def _amount(resource: str, value: float) -> str:
    if resource == "memory":
        return f"{value / 2**30:.1f}Gi"
    if resource == "cpu":
        return format_cpu(value)
    return f"{value:g}"


def _apply(
    deps: Deps,
    ns: str,
    desired: list[Obj],
    deployments: list[Obj],
    problem: Problem,
    stranded: set[int],
) -> tuple[int, int]:
    have = {d["metadata"]["name"]: d for d in deployments}
    applied = 0
    for dep in desired:
        old = have.get(dep["metadata"]["name"])
        want = dep["metadata"]["annotations"][ANNOTATION_SPEC_HASH]
        if (
            old is not None
            and (old["metadata"].get("annotations") or {}).get(ANNOTATION_SPEC_HASH) == want
        ):
            continue
        deps.kube.apply_deployment(dep)
        applied += 1
    keep = {d["metadata"]["name"] for d in desired}
    idents = {
        (problem.instances[i].robot, problem.instances[i].module, problem.instances[i].replica)
        for i in stranded
    }
    pruned = 0
    for name, dep in have.items():
        if name in keep or identity_of(dep) in idents:
            continue  # stranded instances keep their Deployment until their node returns
        deps.kube.delete_deployment(ns, name)
        pruned += 1
    return applied, pruned


def _status(
    fleet: RobotFleet,
    problem: Problem,
    desired: list[Obj],
    roll: Any,
    stranded: set[int],
    cached: CachedPlan | None,
    planned: bool,
    baseline: bool,
    generation: int | None,
    old: Obj,
) -> Obj:
    names = [d["metadata"]["name"] for d in desired]
    by_name = dict(zip(names, desired, strict=True))
    placement: list[Obj] = []
    tiers: Counter[str] = Counter()
    index = {(inst.robot, inst.module, inst.replica): i for i, inst in enumerate(problem.instances)}
    for dname, dep in by_name.items():
        ident = identity_of(dep)
        i = index.get(ident, -1) if ident else -1
        if baseline:
            node = roll.bound.get(dname)
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
        tiers[nd.tier.value] += 1
        alloc = problem.nominal if baseline else problem.limits
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
    if roll.moving or stranded:
        msg = f"{len(roll.moving)} module(s) moving to their new node" if roll.moving else ""
        msg = "; ".join(x for x in [msg, *stuck] if x)
        degraded = condition(
            "Degraded", True, "NodeUnavailable" if stranded else "Migrating", msg, generation
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
    status: Obj = {
        "observedGeneration": generation,
        "conditions": merge_conditions(old.get("conditions") or [], [ready_c, sched, degraded]),
        "scheduler": fleet.spec.scheduler.algorithm.value,
        "placement": placement,
        "modulesPlaced": len(placement),
        "modulesTotal": total,
        "split": f"{tiers[Tier.ROBOT.value]}/{tiers[Tier.EDGE.value]}/{tiers[Tier.CLOUD.value]}",
    }
    if cached is not None:
        objectives = cached.schedule.objectives
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
        for entry in placement:
            key = (str(entry["robot"]), str(entry["module"]), int(entry.get("replica", 0)))
            x[index[key]] = problem.node_index(entry["node"])
        values = planning.objective_values(problem, x, False, ["missRate", "missedCycles"])
        status["objectives"] = [{"name": k, "value": finite(v)} for k, v in values.items()]
        status["predictedMissRate"] = finite(values.get("missRate"))
    return status


def _plan_events(deps: Deps, body: Obj, problem: Problem, cached: CachedPlan) -> None:
    p = cached.placement
    split = Counter(problem.nodes[j].tier.value for j in p if j >= 0)
    miss = cached.schedule.objectives.get("missRate")
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
    if cached.moves:
        deps.kube.emit_event(
            body,
            "Normal",
            "Migrated",
            f"Moved {len(cached.moves)} running modules: {', '.join(cached.moves[:10])}",
        )


def _paused(body: Obj, deps: Deps, old: Obj, generation: int | None) -> Outcome:
    ns, name = _key(body)
    status = {
        **old,
        "observedGeneration": generation,
        "conditions": merge_conditions(
            old.get("conditions") or [],
            [
                condition(
                    "Scheduled",
                    False,
                    "Paused",
                    "spec.paused is true: nothing is planned or changed until it is false",
                    generation,
                )
            ],
        ),
    }
    if not same_status(old, status):
        deps.kube.patch_fleet_status(ns, name, status)
    return Outcome(message="paused")


def _fail(body: Obj, deps: Deps, old: Obj, generation: int | None, exc: InvalidSpec) -> None:
    """Ready=False with the precise reason, one Event; nothing that runs is touched."""
    ns, name = _key(body)
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
