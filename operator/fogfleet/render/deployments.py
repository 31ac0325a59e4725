"""Render a fleet's plan into apps/v1 Deployments (pure: dicts in, dicts out, no kubernetes import).

One Deployment per placed (robot, module) instance, bound to its node by a **required node
affinity**, requesting the CPU the plan chose for that node's hardware type
(multi-robot-edge-cloud-scheduling IV-B, "GA-based with limits") with a limit at the fleet's
``cpuLimitPercent`` of it (100: requests = limits, the paper's Guaranteed pods). The
``k8s-default`` baseline renders the same Deployments with the taxonomy's whole allowed node
set as affinity and the module's nominal requests (no limits), so the real kube-scheduler
makes the choice.

Names come from ``render.names`` (``<fleet>-<robot>-<module>-<hash8>``, the hash of the exact
identity; unique across the fleets of a namespace, issue 45); the full identity is in the
annotations, and label values go through ``api.names`` (issue 35).
``fogfleet.io/spec-hash`` lets the controller skip applying what is already there.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fogfleet import API_VERSION
from fogfleet.api.labels import (
    ANNOTATION_MODULE,
    ANNOTATION_NODE,
    ANNOTATION_PLAN,
    ANNOTATION_REPLICA,
    ANNOTATION_ROBOT,
    ANNOTATION_ROLE,
    ANNOTATION_SPEC_HASH,
    HOSTNAME_KEY,
    LABEL_COMPONENT,
    LABEL_FLEET,
    LABEL_INSTANCE,
    LABEL_MANAGED_BY,
    LABEL_MODULE,
    LABEL_ROBOT,
    LABEL_TIER,
    MANAGER,
    ROLE_REMOTE,
    ROLE_STANDBY,
)
from fogfleet.api.names import digest, label_value
from fogfleet.api.v1alpha1.fallback import Fallback
from fogfleet.api.v1alpha1.robotfleet import DEFAULT_CPU_LIMIT_PERCENT
from fogfleet.api.v1alpha1.softwaremodule import ProfileEntry, SoftwareModule
from fogfleet.domain.problem import Instance, Problem
from fogfleet.render.dnn import ROLE_HEAD, ROLE_TAIL, split_body
from fogfleet.render.names import container_name, deployment_name
from fogfleet.render.podtemplate import module_pod_spec, scrape_port
from fogfleet.render.ros import RosWiring, module_env, node_affinity, stay_on_robot

__all__ = [
    "ANNOTATION_MODULE",
    "ANNOTATION_NODE",
    "ANNOTATION_PLAN",
    "ANNOTATION_REPLICA",
    "ANNOTATION_ROBOT",
    "ANNOTATION_ROLE",
    "ANNOTATION_SPEC_HASH",
    "COMPONENT_STANDBY",
    "LABEL_FLEET",
    "LABEL_INSTANCE",
    "LABEL_MANAGED_BY",
    "LABEL_MODULE",
    "LABEL_ROBOT",
    "LABEL_TIER",
    "MANAGER",
    "ROLE_REMOTE",
    "ROLE_STANDBY",
    "Owner",
    "format_cpu",
    "hash_annotation",
    "identity_of",
    "label_value",
    "node_affinity",
    "owner_references",
    "render_fleet",
    "render_instance",
    "spec_hash",
    "spread_replicas",
    "with_spec_hash",
]

COMPONENT_STANDBY = "fallback-standby"


@dataclass(frozen=True)
class Owner:
    """The RobotFleet that owns the Deployments (an ownerReference needs its uid)."""

    name: str
    uid: str


def format_cpu(cores: float) -> str:
    """Cores as a Kubernetes quantity in millicores ("1500m"), rounded up to a whole milli."""
    return f"{int(np.ceil(round(cores * 1000, 6)))}m"


def spec_hash(deployment: Mapping[str, Any]) -> str:
    """Hash of what the Deployment asks for, without the plan id and the hash itself (on the
    Deployment and on its pod template)."""
    body = json.loads(json.dumps(deployment))
    annotations = body.get("metadata", {}).get("annotations", {})
    annotations.pop(ANNOTATION_PLAN, None)
    annotations.pop(ANNOTATION_NODE, None)
    annotations.pop(ANNOTATION_SPEC_HASH, None)
    template = (body.get("spec") or {}).get("template") or {}
    ((template.get("metadata") or {}).get("annotations") or {}).pop(ANNOTATION_SPEC_HASH, None)
    return digest(body, n=16)


def hash_annotation(obj: Mapping[str, Any] | None) -> str | None:
    """The spec hash an object (Deployment, its pod, a Service) was written with, if any."""
    return (((obj or {}).get("metadata") or {}).get("annotations") or {}).get(ANNOTATION_SPEC_HASH)


def identity_of(deployment: Mapping[str, Any]) -> tuple[str, str, int] | None:
    """(robot, module, replica) of a fogfleet Deployment, from its annotations; None for an
    on-board standby (where it runs is not where its instance is placed)."""
    ann = (deployment.get("metadata") or {}).get("annotations") or {}
    if ANNOTATION_MODULE not in ann or ann.get(ANNOTATION_ROLE) == ROLE_STANDBY:
        return None
    try:
        replica = int(ann.get(ANNOTATION_REPLICA, "0"))
    except ValueError:
        return None
    return ann.get(ANNOTATION_ROBOT, ""), ann[ANNOTATION_MODULE], replica


def spread_replicas(pod_spec: dict[str, Any], fleet: str, module: str) -> dict[str, Any]:
    """``pod_spec`` with a topology spread over nodes for a shared module's replicas (issue 35):
    the safety net of the planner's rule (``scheduling.spread``). ``ScheduleAnyway`` never
    blocks a pod, and a replica pinned to its planned node by a required node affinity has one
    candidate node, so the spread cannot contradict the plan: it only steers replicas that
    kube-scheduler places (the ``k8s-default`` baseline, affinity to every allowed node)."""
    selector = {LABEL_FLEET: label_value(fleet), LABEL_MODULE: label_value(module)}
    spread = {
        "maxSkew": 1,
        "topologyKey": HOSTNAME_KEY,
        "whenUnsatisfiable": "ScheduleAnyway",
        "labelSelector": {"matchLabels": selector},
    }
    have = list(pod_spec.get("topologySpreadConstraints") or [])
    pod_spec["topologySpreadConstraints"] = have + ([spread] if spread not in have else [])
    return pod_spec


def _nominal_row(problem: Problem, i: int, j: int) -> ProfileEntry:
    """The row instance ``i`` runs with on node ``j`` without a limit, as the simulator has it
    (``Problem.nominal``: the largest profiled parallelism that fits the node, speed-scaled)."""
    nominal = problem.nominal
    return ProfileEntry(
        hardware_type=problem.nodes[j].hardware_type,
        cpu=format_cpu(float(nominal.cpu_use[i, j])),
        mean_millis=round(float(nominal.exe_mean[i, j]) * 1e3, 3),
        std_millis=round(float(nominal.exe_std[i, j]) * 1e3, 3),
    )


@dataclass(frozen=True)
class _Amounts:
    """What one instance's Deployment asks for on its node: CPU request and the CPU its row
    uses (cores), memory (bytes), GPUs; ``variant``: a standby running a variant module."""

    request: float
    use: float
    memory: float
    gpu: float
    variant: bool


def render_instance(
    problem: Problem,
    i: int,
    module: SoftwareModule,
    nodes: Sequence[int],
    *,
    baseline: bool = False,
    with_limits: bool = True,
    cpu_limit_percent: int = DEFAULT_CPU_LIMIT_PERCENT,
    owner: Owner | None = None,
    plan_id: str = "",
    wiring: RosWiring | None = None,
    role: str = "",
    fallback: Fallback | None = None,
    tail: int | None = None,
) -> dict[str, Any]:
    """The Deployment of instance ``i`` allowed on ``nodes`` (one node unless ``baseline``).

    Without limits (``baseline``, or a plan made for the nominal allocation such as
    ``onboard``) it requests the module's nominal CPU, has no limit and runs its node's nominal
    row, as the simulator models such a plan. ``role`` with ``fallback``: the instance
    offloaded with an on-board fallback (``remote``) or its standby on the robot (``standby``,
    requesting the share its robot holds for it: ``Problem.fallback_reserve``). A split
    network's (``spec.dnn``) pods: ``tail`` is the node its plan runs the tail on (its robot:
    none, the head pod answers alone); the pod on ``tail`` is its tail, the one on the robot
    its head (``render.dnn``).
    """
    inst = problem.instances[i]
    home = int(problem.home[i])
    name = deployment_name(problem.fleet, inst, role)
    with_limits = with_limits and not baseline
    j = nodes[0]
    amounts = _amounts(problem, i, j, with_limits, role, fallback)
    resources = _resources(problem, j, amounts, with_limits, cpu_limit_percent)
    tier = "" if baseline else problem.nodes[j].tier.value
    selector = {LABEL_FLEET: label_value(problem.fleet), LABEL_INSTANCE: name}
    labels, annotations = _labels_and_annotations(inst, selector, tier, role)
    pod_annotations = dict(annotations)
    port = scrape_port(module.spec.template)
    if port:
        pod_annotations |= {"prometheus.io/scrape": "true", "prometheus.io/port": str(port)}
    node = problem.nodes[j]
    owned_env = module_env(
        wiring,
        fleet=problem.fleet,
        robot=inst.robot,
        module=module,
        tier=tier or "",
        node="" if baseline else node.node_name,
        hardware_type="" if baseline else node.hardware_type,
        # the row it plays is the one it was planned to run: a degraded instance requests less
        # than its row needs and bursts to it (its limit), as the planner and simulator have it
        cpu=format_cpu(amounts.use) if with_limits else "",
        node_rows=None
        if with_limits
        else {problem.nodes[k].node_name: _nominal_row(problem, i, k) for k in nodes},
        role=role,
        fallback=fallback if role else None,
        stands_in_for=inst.module if module.metadata.name != inst.module else "",
        remote_cycle_millis=float(problem.cycle[i]) * 1e3 if amounts.variant else None,
        speed_factor=node.speed_factor,
        split=None if tail is None else split_body(problem, module, i, tail),
        workload_role="" if tail is None else (ROLE_TAIL if j == tail != home else ROLE_HEAD),
    )
    pod_spec = module_pod_spec(
        module,
        container_name=container_name(module.metadata.name),
        affinity=node_affinity([problem.nodes[k].node_name for k in nodes]),
        resources=resources,
        owned_env=owned_env,
    )
    if tier == "robot":
        stay_on_robot(pod_spec)
    if not inst.robot and role != ROLE_STANDBY:
        spread_replicas(pod_spec, problem.fleet, inst.module)
    metadata = _metadata(name, problem.namespace, labels, annotations, owner)
    dep = _deployment(metadata, selector, labels, pod_annotations, pod_spec)
    annotations[ANNOTATION_SPEC_HASH] = spec_hash(dep)
    # the pods carry it too: a running pod of the current spec is then known from the pod
    # alone, without waiting for the Deployment's status (the fleet's Ready condition)
    pod_annotations[ANNOTATION_SPEC_HASH] = annotations[ANNOTATION_SPEC_HASH]
    if plan_id:
        annotations[ANNOTATION_PLAN] = plan_id
    if len(nodes) == 1 and not baseline:
        annotations[ANNOTATION_NODE] = node.node_name  # after the hash: the affinity's twin
    return dep


def _amounts(
    problem: Problem, i: int, j: int, with_limits: bool, role: str, fallback: Fallback | None
) -> _Amounts:
    """Instance ``i``'s amounts on node ``j`` under the allocation its plan was made for; a
    standby's are its share of its robot's reserve (a variant's: its own row and needs)."""
    alloc = problem.limits if with_limits else problem.nominal
    request, use = float(alloc.cpu_request[i, j]), float(alloc.cpu_use[i, j])
    mem, gpu = float(problem.memory[i]), float(problem.gpu[i])
    # a standby with its own row: a variant module's, or a split network's head and local model
    variant = (
        role == ROLE_STANDBY
        and problem.fallback_variant is not None
        and bool(problem.fallback_variant[i])
    )
    if role == ROLE_STANDBY and problem.fallback_row is not None:
        # its share of the robot's reserve (Problem.fallback_share): the row it runs with
        request = use = min(request, float(problem.fallback_row[i, 0]))
        if variant:  # a variant module: its own row, memory and GPUs
            request = use = float(problem.fallback_row[i, 0])
            if problem.fallback_need is not None:
                mem, gpu = (float(v) for v in problem.fallback_need[i])
    return _Amounts(request, use, mem, gpu, variant)


def _resources(
    problem: Problem, j: int, amounts: _Amounts, with_limits: bool, cpu_limit_percent: int
) -> dict[str, Any]:
    """The container's requests and, planned with limits, its limits."""
    request = amounts.request
    requests: dict[str, str] = {
        "cpu": format_cpu(request),
        "memory": str(int(np.ceil(amounts.memory))),
    }
    resources: dict[str, Any] = {"requests": requests}
    if with_limits:
        limits = dict(requests)
        # what its row needs (a degraded instance, Problem.with_levels: more than it is
        # guaranteed), with the fleet's headroom for bursts (SchedulerSettings.cpu_limit_percent)
        limit = amounts.use * cpu_limit_percent / 100
        # never beyond what the node has for pods: more buys nothing, and a node whose CPU is
        # a cgroup quota (cgroup v1 checks a child's quota against its parent's, as on the
        # e2e bed's real nodes) refuses to start the container
        limit = min(limit, max(float(problem.capacity[j, 0]), request))
        if limit > request:
            limits["cpu"] = format_cpu(limit)
        if amounts.gpu > 0:
            limits["nvidia.com/gpu"] = str(int(amounts.gpu))
        resources["limits"] = limits
    return resources


def _labels_and_annotations(
    inst: Instance, selector: Mapping[str, str], tier: str, role: str
) -> tuple[dict[str, str], dict[str, str]]:
    """The Deployment's (and its pods') labels, and its annotations naming the instance."""
    labels = {
        **selector,
        LABEL_MANAGED_BY: MANAGER,
        LABEL_ROBOT: label_value(inst.robot),
        LABEL_MODULE: label_value(inst.module),
    }
    if tier:
        labels[LABEL_TIER] = tier
    annotations = {
        ANNOTATION_ROBOT: inst.robot,
        ANNOTATION_MODULE: inst.module,
        ANNOTATION_REPLICA: str(inst.replica),
    }
    if role == ROLE_STANDBY:
        labels[LABEL_COMPONENT] = COMPONENT_STANDBY
        annotations[ANNOTATION_ROLE] = ROLE_STANDBY
    return labels, annotations


def _metadata(
    name: str,
    namespace: str,
    labels: dict[str, str],
    annotations: dict[str, str],
    owner: Owner | None,
) -> dict[str, Any]:
    """The Deployment's metadata, owned by its RobotFleet when ``owner`` is given."""
    metadata: dict[str, Any] = {
        "name": name,
        "namespace": namespace,
        "labels": labels,
        "annotations": annotations,
    }
    if owner is not None:
        metadata["ownerReferences"] = owner_references(owner)
    return metadata


def owner_references(owner: Owner | None) -> list[dict[str, Any]]:
    """The ownerReferences of an object the fleet ``owner`` owns (none without an owner)."""
    if owner is None:
        return []
    return [
        {
            "apiVersion": API_VERSION,
            "kind": "RobotFleet",
            "name": owner.name,
            "uid": owner.uid,
            "controller": True,
            "blockOwnerDeletion": True,
        }
    ]


def with_spec_hash(obj: Mapping[str, Any]) -> dict[str, Any]:
    """``obj`` with its spec-hash annotation (on its own copy of the metadata): how the apply
    engine knows an object there is unchanged."""
    meta = obj["metadata"]
    annotations = {**(meta.get("annotations") or {}), ANNOTATION_SPEC_HASH: spec_hash(obj)}
    return {**obj, "metadata": {**meta, "annotations": annotations}}


def _deployment(
    metadata: dict[str, Any],
    selector: Mapping[str, str],
    labels: dict[str, str],
    pod_annotations: dict[str, str],
    pod_spec: dict[str, Any],
) -> dict[str, Any]:
    """One replica, rolled over with ``maxUnavailable: 1``."""
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": metadata,
        "spec": {
            "replicas": 1,
            "selector": {"matchLabels": selector},
            # maxUnavailable 1: a module leaving a lost node is started elsewhere at once
            "strategy": {
                "type": "RollingUpdate",
                "rollingUpdate": {"maxSurge": 1, "maxUnavailable": 1},
            },
            "template": {
                "metadata": {"labels": labels, "annotations": pod_annotations},
                "spec": pod_spec,
            },
        },
    }


def render_fleet(
    problem: Problem,
    modules: Mapping[str, SoftwareModule],
    placement: Sequence[int] | np.ndarray[Any, Any] | None,
    *,
    baseline: bool = False,
    with_limits: bool = True,
    cpu_limit_percent: int = DEFAULT_CPU_LIMIT_PERCENT,
    owner: Owner | None = None,
    plan_id: str = "",
    wiring: RosWiring | None = None,
    fallbacks: Mapping[str, Fallback] | None = None,
) -> list[dict[str, Any]]:
    """Deployments for a fleet, in instance order.

    ``placement[i]`` is the chosen node index (``-1``: not placed, no Deployment). With
    ``baseline`` (the ``k8s-default`` scheduler) the placement is ignored: every instance with a
    non-empty gene space gets affinity to all of it and kube-scheduler decides.
    ``with_limits`` is the plan's (``Schedule.with_limits``): False renders the nominal
    allocation (see ``render_instance``). ``cpu_limit_percent`` is the fleet's
    ``spec.scheduler.cpuLimitPercent``.
    ``modules`` maps SoftwareModule names to the objects (their container templates).
    ``fallbacks`` (module name -> its effective fallback, ``domain.fallback``): an instance
    the plan offloads and whose robot holds its reserve gets a standby Deployment on the robot
    next to its own (``render_instance`` roles).
    """
    out: list[dict[str, Any]] = []

    def one(
        i: int,
        nodes: list[int],
        role: str = "",
        fallback: Fallback | None = None,
        tail: int | None = None,
    ) -> dict[str, Any]:
        name = problem.instances[i].module
        if role == ROLE_STANDBY and fallback is not None and fallback.variant is not None:
            name = fallback.variant  # the standby runs the lighter variant module
        return render_instance(
            problem,
            i,
            modules[name],
            nodes,
            baseline=baseline,
            with_limits=with_limits,
            cpu_limit_percent=cpu_limit_percent,
            owner=owner,
            plan_id=plan_id,
            wiring=wiring,
            role=role,
            fallback=fallback,
            tail=tail,
        )

    for i, inst in enumerate(problem.instances):
        if baseline:
            nodes = [int(j) for j in np.flatnonzero(problem.allowed[i])]
            if nodes:
                out.append(one(i, nodes))
            continue
        if placement is None or int(placement[i]) < 0:
            continue
        j, home = int(placement[i]), int(problem.home[i])
        if modules[inst.module].spec.dnn is not None:  # a split network (render.dnn)
            out.append(one(i, [j], ROLE_REMOTE if j != home else "", tail=j))
            if j != home:
                out.append(one(i, [home], ROLE_STANDBY, tail=j))
            continue
        fallback = (fallbacks or {}).get(inst.module)
        if fallback is None or not problem.standing_by[i] or j == home:
            out.append(one(i, [j]))
            continue
        # offloaded with an on-board fallback: the remote instance and its standby
        out.append(one(i, [j], ROLE_REMOTE, fallback))
        out.append(one(i, [home], ROLE_STANDBY, fallback))
    return out
