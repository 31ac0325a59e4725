"""Apply a fleet's ROS 2 wiring: one discovery server (Service + Deployment) per robot, and
the fleet's NetworkPolicies (each robot's pods talk with each other and with the shared
services; metrics ports are open; ``render.ros.fleet_network_policies``). Policies of robots
that left the fleet are deleted.

The Service is applied first, so its cluster IP (allocated once by the API server and kept)
can go into every module's ``ROS_DISCOVERY_SERVER``: no cluster DNS is needed. Servers of
robots that left the fleet are deleted; owner references remove the rest with the fleet.
Services and Deployments carry a spec-hash annotation: an unchanged one is not written again
(a reconcile at 1000 robots would otherwise re-apply 1000 Services), a changed one is applied
with the fleet's other writes in parallel.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.adapters.ports import KubePort
from fogfleet.api.labels import ANNOTATION_SPEC_HASH, LABEL_COMPONENT, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.controllers.parallel import run_all
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import Owner, hash_annotation, spec_hash
from fogfleet.render.ros import (
    COMPONENT_DISCOVERY,
    RosWiring,
    discovery_servers,
    fleet_network_policies,
    service_address,
)

__all__ = ["apply_ros_wiring", "is_ros_object"]

Obj = dict[str, Any]


def is_ros_object(obj: Mapping[str, Any]) -> bool:
    labels = (obj.get("metadata") or {}).get("labels") or {}
    return labels.get(LABEL_COMPONENT) == COMPONENT_DISCOVERY


def _hashed(obj: Obj) -> Obj:
    """The object with its spec-hash annotation (on its own copy of the metadata)."""
    meta = obj["metadata"]
    annotations = {**(meta.get("annotations") or {}), ANNOTATION_SPEC_HASH: spec_hash(obj)}
    return {**obj, "metadata": {**meta, "annotations": annotations}}


def _owner_refs(owner: Owner | None) -> list[Obj]:
    if owner is None:
        return []
    return [
        {
            "apiVersion": "fogfleet.io/v1alpha1",
            "kind": "RobotFleet",
            "name": owner.name,
            "uid": owner.uid,
            "controller": True,
            "blockOwnerDeletion": True,
        }
    ]


def apply_ros_wiring(
    kube: KubePort,
    fleet: RobotFleet,
    problem: Problem,
    owner: Owner | None,
    fleet_labels: Mapping[str, str],
    modules: Iterable[SoftwareModule] = (),
    concurrency: int = 1,
) -> RosWiring | None:
    """Apply every robot's discovery server; the wiring the modules are rendered with."""
    settings = fleet.spec.ros
    if not settings.enabled:
        return None
    ns = problem.namespace
    labels = {**fleet_labels, LABEL_MANAGED_BY: MANAGER}
    have = {
        d["metadata"]["name"]: d
        for d in kube.list_deployments(ns, fleet_labels)
        if is_ros_object(d)
    }
    services = {
        s["metadata"]["name"]: s for s in kube.list_services(ns, fleet_labels) if is_ros_object(s)
    }
    names: dict[str, str] = {}  # robot -> its discovery server's Service (and Deployment)
    stored: dict[str, Obj] = {}
    to_apply: list[Obj] = []
    deployments: list[Obj] = []
    for robot, service, deployment in discovery_servers(
        problem, settings, labels, _owner_refs(owner)
    ):
        service, deployment = _hashed(service), _hashed(deployment)
        name = service["metadata"]["name"]
        old = services.get(name)
        if (
            old is not None
            and hash_annotation(old) == hash_annotation(service)
            and (old.get("spec") or {}).get("clusterIP")
        ):
            stored[name] = old  # unchanged, its cluster IP allocated: nothing to write
        else:
            to_apply.append(service)
        names[robot] = name
        if hash_annotation(have.get(deployment["metadata"]["name"])) != hash_annotation(deployment):
            deployments.append(deployment)

    def apply_service(body: Obj) -> None:
        result = kube.apply_service(body)
        stored[body["metadata"]["name"]] = result if result.get("spec") else body

    # Services first: their cluster IPs go into every module's ROS_DISCOVERY_SERVER
    run_all([functools.partial(apply_service, body) for body in to_apply], concurrency)
    servers = {robot: service_address(stored[name]) for robot, name in names.items()}
    run_all([functools.partial(kube.apply_deployment, d) for d in deployments], concurrency)
    ports = sorted({p for m in modules for p in m.spec.template.metrics_ports()})
    policies = fleet_network_policies(
        fleet=problem.fleet,
        namespace=ns,
        selector=dict(fleet_labels),
        robots=sorted({inst.robot for inst in problem.instances}),
        metrics_ports=ports,
        owner_refs=_owner_refs(owner),
    )
    run_all([functools.partial(kube.apply_network_policy, p) for p in policies], concurrency)
    wanted = set(names.values())
    stale = [functools.partial(kube.delete_deployment, ns, n) for n in have if n not in wanted]
    stale += [functools.partial(kube.delete_service, ns, n) for n in services if n not in wanted]
    keep = {p["metadata"]["name"] for p in policies}
    stale += [
        functools.partial(kube.delete_network_policy, ns, p["metadata"]["name"])
        for p in kube.list_network_policies(ns, fleet_labels)
        if p["metadata"]["name"] not in keep
    ]
    run_all(stale, concurrency)
    return RosWiring(settings, servers)
