"""Apply a fleet's ROS 2 wiring: one discovery server (Service + Deployment) per robot, and
the fleet's NetworkPolicy (its pods talk to each other; metrics ports are open).

The Service is applied first, so its cluster IP (allocated once by the API server and kept)
can go into every module's ``ROS_DISCOVERY_SERVER``: no cluster DNS is needed. Servers of
robots that left the fleet are deleted; owner references remove the rest with the fleet.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.adapters.ports import KubePort
from fogfleet.api.labels import ANNOTATION_SPEC_HASH, LABEL_COMPONENT, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import Owner, _dns, spec_hash
from fogfleet.render.ros import (
    COMPONENT_DISCOVERY,
    RosWiring,
    discovery_servers,
    fleet_network_policy,
    service_address,
)

__all__ = ["apply_ros_wiring", "is_ros_object"]

Obj = dict[str, Any]


def is_ros_object(obj: Mapping[str, Any]) -> bool:
    labels = (obj.get("metadata") or {}).get("labels") or {}
    return labels.get(LABEL_COMPONENT) == COMPONENT_DISCOVERY


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
) -> RosWiring | None:
    """Apply every robot's discovery server; the wiring the modules are rendered with."""
    settings = fleet.spec.ros
    if not settings.enabled:
        return None
    ns = problem.namespace
    labels = {**fleet_labels, LABEL_MANAGED_BY: MANAGER}
    servers: dict[str, str] = {}
    wanted: set[str] = set()
    have = {
        d["metadata"]["name"]: d
        for d in kube.list_deployments(ns, fleet_labels)
        if is_ros_object(d)
    }
    for robot, service, deployment in discovery_servers(
        problem, settings, labels, _owner_refs(owner), _dns
    ):
        name = service["metadata"]["name"]
        wanted.add(name)
        stored = kube.apply_service(service)
        servers[robot] = service_address(stored if stored.get("spec") else service)
        deployment["metadata"]["annotations"] = {ANNOTATION_SPEC_HASH: spec_hash(deployment)}
        old = have.get(name)
        old_hash = ((old or {}).get("metadata", {}).get("annotations") or {}).get(
            ANNOTATION_SPEC_HASH
        )
        if old_hash != deployment["metadata"]["annotations"][ANNOTATION_SPEC_HASH]:
            kube.apply_deployment(deployment)
    ports = sorted({p for m in modules for p in m.spec.template.metrics_ports()})
    kube.apply_network_policy(
        fleet_network_policy(
            name=_dns(f"{problem.fleet}-pods")[:63],
            namespace=ns,
            selector=dict(fleet_labels),
            metrics_ports=ports,
            owner_refs=_owner_refs(owner),
        )
    )
    for name in set(have) - wanted:
        kube.delete_deployment(ns, name)
    for svc in kube.list_services(ns, fleet_labels):
        if is_ros_object(svc) and svc["metadata"]["name"] not in wanted:
            kube.delete_service(ns, svc["metadata"]["name"])
    return RosWiring(settings, servers)
