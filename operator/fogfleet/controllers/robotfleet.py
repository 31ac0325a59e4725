"""The RobotFleet controller: one level-based ``reconcile(fleet, deps) -> Outcome``.

Create, update, resume, the drift timer and every debounced trigger (a module, ComputeNode or
Node changed; a Deployment or Pod moved) call the same function. When nothing it reads but the
rollout's progress changed since the last full pass (``stamp.input_stamp``), it only refreshes
the status from the rendered Deployments it kept. Otherwise it plans
only when the planning inputs changed (fingerprint cache), keeps running modules in place
unless the new plan is better by the migration margin, applies with server-side apply, prunes
stale Deployments, and writes the status in one patch. Invalid input (bad spec, dangling
reference, a fleet that cannot fit) touches nothing that runs: it sets ``Ready=False`` with the
reason, posts an Event and re-raises so the handler can map it.

Blocking (API calls, the GA): run it in a worker thread (``asyncio.to_thread``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from fogfleet.api.labels import LABEL_FLEET
from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.controllers.ros import apply_ros_wiring, is_ros_object
from fogfleet.domain.build import build_problem
from fogfleet.domain.fallback import fleet_fallbacks, variant_names
from fogfleet.domain.linkhealth import planned_links
from fogfleet.domain.network import uplink
from fogfleet.errors import Infeasible, InvalidSpec
from fogfleet.render.deployments import (
    Owner,
    label_value,
    render_fleet,
)
from fogfleet.scheduling import stickiness
from fogfleet.scheduling.objectives import module_miss_rates

from .apply import apply_fleet, owned
from .deps import CachedPlan, Deps, FleetKey, Rendered, fleet_key
from .drift_report import drift_events, drift_report
from .fleet_plan import plan_fleet
from .fleet_status import fleet_status, placement_entries, plan_events, report_failure
from .inputs import current_placement, gather
from .links import link_events, link_report
from .observed import profile_corrections
from .profiling import PROFILING_POLL_SECONDS, profile_first, report_waiting
from .stamp import RESYNC_MAX_DEFER_SECONDS, DeploymentStamps, input_stamp, resync_overdue
from .status import (
    condition,
    merge_conditions,
    rollout,
    same_status,
    scaling_status,
)

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
    waiting: int = 0  # modules not yet running where planned (rolling out or moving)
    unsettled: frozenset[str] = frozenset()  # their Deployments' names
    status_write_seconds: float = 0.0  # spent patching the fleet's status


def forget(deps: Deps, key: FleetKey) -> None:
    """The fleet is gone: drop its cache and references (its Deployments go with it)."""
    deps.plans.pop(key, None)
    deps.rendered.pop(key, None)
    deps.placements.pop(key, None)
    deps.deployment_stamps.pop(key, None)
    deps.failures.pop(key, None)
    deps.links.pop(key, None)
    deps.standbys_active.pop(key, None)
    deps.drift.pop(key, None)
    deps.drift_epoch.pop(key, None)
    deps.refs.forget(key)


def reconcile(body: Obj, deps: Deps) -> Outcome:
    """Bring the cluster to the fleet's desired state. See the module docstring."""
    key = fleet_key(body)
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
        report_failure(body, deps, old_status, generation, exc)
        raise


def _profiled(raw_modules: Iterable[Mapping[str, Any]]) -> tuple[tuple[str, str], ...]:
    """What the modules' automatic profiling has recorded (a new profile is a new input)."""
    return tuple(
        sorted(
            (
                str(m["metadata"]["name"]),
                repr(((m.get("status") or {}).get("profiling") or {}).get("rows")),
            )
            for m in raw_modules
            if (m.get("status") or {}).get("profiling")
        )
    )


def _modules_in(catalog: Catalog, ns: str) -> dict[str, SoftwareModule]:
    """The catalog's SoftwareModules of the fleet's namespace, by name."""
    return {
        m.metadata.name: m
        for m in catalog.modules.values()
        if (m.metadata.namespace or "default") == ns
    }


def _record_references(
    deps: Deps, key: FleetKey, fleet: RobotFleet, modules: set[str] | None = None
) -> None:
    names = set(fleet.spec.robots) | set(fleet.spec.nodes)
    selector = fleet.spec.robot_selector is not None or fleet.spec.node_selector is not None
    wanted = modules if modules is not None else {m.name for m in fleet.spec.modules}
    deps.refs.record(key, names, set(), wanted, selector)


def _reconcile(
    body: Obj, fleet: RobotFleet, deps: Deps, old_status: Obj, generation: int | None
) -> Outcome:
    key = fleet_key(body)
    ns, name = key
    kube = deps.kube
    selector = {LABEL_FLEET: label_value(name)}
    listed = [d for d in kube.list_deployments(ns, selector) if owned(d, body)]
    deployments = [d for d in listed if not is_ros_object(d)]
    raw_modules = kube.list_modules(ns)
    compute_nodes, nodes = kube.list_compute_nodes(), kube.list_nodes()
    # a robot's link measured worse than declared is planned with the measured figures
    measured = planned_links(deps.links.get(key, {}))
    # modules' profiles corrected by what ran (controllers/observed.py)
    corrections = profile_corrections(raw_modules)
    learnt = (tuple(sorted(corrections.items())), _profiled(raw_modules))
    remembered = deps.deployment_stamps.setdefault(key, DeploymentStamps())
    stamp = (
        *input_stamp(body, raw_modules, compute_nodes, nodes, listed, remembered),
        measured,
        learnt,
    )
    last = deps.rendered.pop(key, None)
    if last is not None and last.stamp == stamp:
        deps.rendered[key] = last
        overdue = resync_overdue(last.at, last.seconds, deps.full_reconcile_seconds)
        outcome, old_status = _finish(
            body, fleet, deps, last, deployments, False, old_status, generation
        )
        if overdue is None or (outcome.waiting and overdue < RESYNC_MAX_DEFER_SECONDS):
            return outcome
        deps.rendered.pop(key, None)  # a full pass that fails leaves nothing to reuse
        log.debug("RobotFleet %s/%s: re-rendering a %.0f s old render", ns, name, overdue)
    else:
        log.debug("RobotFleet %s/%s: inputs changed, full reconcile", ns, name)
    started = time.monotonic()
    inputs = gather(fleet, compute_nodes, raw_modules, nodes)
    modules = _modules_in(inputs.catalog, ns)
    # the variants the fleet's standbys run: a change to one (or its creation) re-plans it
    wanted = {m.name for m in fleet.spec.modules} | variant_names(fleet.spec, modules)
    _record_references(deps, key, fleet, wanted)
    _raise_broken_references(fleet, inputs.broken)
    # modules with profiling auto are planned once their profiles are known (issue 10)
    waiting, recorded = profile_first(deps, fleet, inputs.catalog, raw_modules)
    if waiting:
        message = report_waiting(body, deps, old_status, generation, waiting)
        poll = None if waiting.failed else PROFILING_POLL_SECONDS
        return Outcome(requeue_after=poll, message=message)
    if recorded:  # the rows just written are part of the modules now
        learnt = (learnt[0], _profiled(raw_modules))
        inputs = gather(fleet, compute_nodes, raw_modules, nodes)
        modules = _modules_in(inputs.catalog, ns)
    problem = build_problem(
        fleet,
        inputs.catalog,
        current_placement(deployments),
        scaling_pools(raw_modules),
        measured,
        corrections,
    )
    deps.refs.record(
        key,
        {n.name for n in problem.nodes},
        {n.node_name for n in problem.nodes},
        wanted,
        fleet.spec.robot_selector is not None or fleet.spec.node_selector is not None,
    )
    unavailable = {
        j: inputs.unavailable[n.name]
        for j, n in enumerate(problem.nodes)
        if n.name in inputs.unavailable
    }
    # a robot whose link is planned as declared again after a bad spell: its modules go
    # where the plan puts them, not where the bad link had them moved (linkhealth)
    recovered = set(last.measured) - set(measured) if last is not None else set()
    if recovered:
        log.info(
            "RobotFleet %s/%s: %s planned with the declared link again",
            ns,
            name,
            ", ".join(sorted(recovered)),
        )
        problem = stickiness.release_robots(
            problem, [j for j, n in enumerate(problem.nodes) if n.name in recovered]
        )
    before = problem.current
    problem, stranded = stickiness.mask_unavailable(problem, unavailable)
    never = {i: why for i, why in problem.reasons.items() if i not in stranded}
    if never:
        raise Infeasible(f"RobotFleet/{name}", "spec.modules", "; ".join(never.values()))
    owner = Owner(name, body["metadata"]["uid"]) if body["metadata"].get("uid") else None
    baseline = fleet.spec.scheduler.algorithm is SchedulerName.K8S_DEFAULT
    cached: CachedPlan | None = None
    planned = False
    if not baseline:
        previous = last.problem if last is not None else None
        cached, planned = plan_fleet(deps, key, problem, fleet, before, previous)
        problem = problem.with_levels(cached.schedule.levels)  # a degraded plan's CPU amounts
    # after planning: an infeasible fleet gets nothing applied, not even its discovery servers
    wiring = apply_ros_wiring(
        deps.kube, fleet, problem, owner, selector, modules.values(), deps.api_concurrency
    )
    if baseline or cached is None:
        desired = render_fleet(problem, modules, None, baseline=True, owner=owner, wiring=wiring)
    else:
        desired = render_fleet(
            problem,
            modules,
            cached.placement,
            with_limits=cached.schedule.with_limits,
            cpu_limit_percent=fleet.spec.scheduler.cpu_limit_percent,
            fallbacks=fleet_fallbacks(fleet.spec, modules),
            owner=owner,
            plan_id=cached.plan_id,
            wiring=wiring,
        )
    applied, pruned = apply_fleet(deps, ns, desired, deployments, problem, stranded)
    if applied or pruned:
        deps.metrics.count_apply(name, applied, pruned)
    # what we wrote (modules' and discovery servers' Deployments) is what the next stamp sees
    listed = [d for d in kube.list_deployments(ns, selector) if owned(d, body)]
    deployments = [d for d in listed if not is_ros_object(d)]
    done = time.monotonic()
    rendered = Rendered(
        (
            *input_stamp(body, raw_modules, compute_nodes, nodes, listed, remembered),
            measured,
            learnt,
        ),
        done,
        done - started,
        problem,
        desired,
        frozenset(stranded),
        cached,
        baseline,
        robots={
            nd.name: (nd.node_name, uplink(inputs.catalog.nodes[nd.name].spec))
            for nd in problem.nodes
            if nd.tier is Tier.ROBOT and nd.name in inputs.catalog.nodes
        },
        link_health=fleet.spec.link_health,
        modules=frozenset(m.name for m in fleet.spec.modules),
        measured=measured,
        drift=fleet.spec.drift,
        predicted=(
            module_miss_rates(problem, cached.placement, cached.schedule.with_limits)
            if cached is not None and not baseline
            else {}
        ),
        hardware={
            nd.spec.hardware_type: nd
            for nd in inputs.catalog.nodes.values()
            if nd.metadata.name in {n.name for n in problem.nodes}
        },
    )
    deps.rendered[key] = rendered
    outcome, _ = _finish(body, fleet, deps, rendered, deployments, planned, old_status, generation)
    if planned and cached is not None:
        plan_events(deps, body, problem, cached)
    return replace(
        outcome,
        applied=applied,
        pruned=pruned,
        migrations=cached.migrations if (cached and planned) else 0,
    )


def _finish(
    body: Obj,
    fleet: RobotFleet,
    deps: Deps,
    rendered: Rendered,
    deployments: list[Obj],
    planned: bool,
    old_status: Obj,
    generation: int | None,
) -> tuple[Outcome, Obj]:
    """The status from where the rendered Deployments stand (one patch, only if it changed),
    and the fleet's status now."""
    ns, name = fleet_key(body)
    pods = deps.kube.list_pods(ns, {LABEL_FLEET: label_value(name)})
    roll = rollout(rendered.desired, deployments, pods)
    placement = placement_entries(
        rendered.problem, rendered.desired, roll, rendered.plan, rendered.baseline
    )
    if deps.placements.get((ns, name)) != placement:  # the usage pass reads it (usage.py)
        deps.placements[(ns, name)] = placement  # replaced only when it changed
    stranded = set(rendered.stranded)
    links = link_report(rendered, deps.links.get((ns, name)), deps.standbys_active.get((ns, name)))
    drift = drift_report(rendered, deps.drift.get((ns, name)))
    status = fleet_status(
        fleet,
        rendered.problem,
        rendered.desired,
        placement,
        roll,
        stranded,
        rendered.plan,
        planned,
        rendered.baseline,
        generation,
        old_status,
        links,
        drift,
    )
    ready = not roll.waiting and not roll.moving and not stranded
    now_status = old_status
    written = 0.0
    if not same_status(old_status, status):
        t0 = time.perf_counter()
        deps.kube.patch_fleet_status(ns, name, status)
        written = time.perf_counter() - t0
        now_status = status
        for kind, reason, message in [
            *link_events(old_status.get("links") or [], links.entries),
            *drift_events(old_status.get("measured") or [], drift.entries),
        ]:
            deps.kube.emit_event(body, kind, reason, message)
        if ready != _is_ready(old_status):
            log.info(
                "RobotFleet %s/%s is %sReady: %s",
                ns,
                name,
                "" if ready else "not ",
                _ready_message(status),
            )
    outcome = Outcome(
        planned=planned,
        ready=ready,
        requeue_after=None if ready else deps.requeue_seconds,
        message=status["conditions"][0]["message"],
        waiting=len(roll.waiting) + len(roll.moving),
        unsettled=frozenset(roll.waiting).union(roll.moving),
        status_write_seconds=written,
    )
    return outcome, now_status


def scaling_pools(modules: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """The autoscaler's last decision per shared module: {module: {tier: replicas}}.

    Read from the SoftwareModules as the API server sends them (one namespace's): the
    catalog's modules are parsed without their status (``inputs.gather``), so they never
    carry ``status.scaling``. A status this operator did not write in this shape is ignored."""
    pools: dict[str, dict[str, int]] = {}
    for raw in modules:
        scaling = scaling_status(raw)
        if scaling is not None:
            tiers = {p.tier: p.replicas for p in scaling.pools}
            pools[str(raw["metadata"]["name"])] = tiers or {"any": scaling.desired_replicas}
    return pools


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


def _is_ready(status: Obj) -> bool:
    return any(
        c.get("type") == "Ready" and c.get("status") == "True"
        for c in status.get("conditions") or []
    )


def _ready_message(status: Obj) -> str:
    return next(
        (str(c.get("message")) for c in status.get("conditions") or [] if c.get("type") == "Ready"),
        "",
    )


def _paused(body: Obj, deps: Deps, old: Obj, generation: int | None) -> Outcome:
    ns, name = fleet_key(body)
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
