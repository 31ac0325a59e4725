"""A fleet's ROS 2 wiring as objects: one discovery server (a Service and a Deployment) per
robot of the plan, and the fleet's NetworkPolicies (each robot's pods talk with each other and
with the shared services; metrics ports are open; ``render.ros.fleet_network_policies``).

Pure: the objects, each with its spec hash, for the operator's one apply engine
(``controllers/fleet/apply.py``). The Services are applied first: their cluster IPs
(allocated once by the API server and kept) go into every module's ``ROS_DISCOVERY_SERVER``
(``RosObjects.wiring``), so no cluster DNS is needed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.api.labels import LABEL_COMPONENT, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.v1alpha1.robotfleet import RosSettings
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import Owner, owner_references, with_spec_hash
from fogfleet.render.relays import COMPONENT_RELAY
from fogfleet.render.ros import (
    COMPONENT_DISCOVERY,
    RosWiring,
    discovery_servers,
    fleet_network_policies,
    service_address,
)

__all__ = ["RosObjects", "is_ros_object", "ros_objects"]

Obj = dict[str, Any]


def is_ros_object(obj: Mapping[str, Any]) -> bool:
    """Whether ``obj`` is part of a fleet's ROS 2 wiring: a discovery server's Service or
    Deployment, or a robot's relay to the managed clusters."""
    labels = (obj.get("metadata") or {}).get("labels") or {}
    return labels.get(LABEL_COMPONENT) in (COMPONENT_DISCOVERY, COMPONENT_RELAY)


@dataclass(frozen=True)
class RosObjects:
    """A fleet's ROS 2 wiring as it should be."""

    settings: RosSettings
    services: list[Obj]  # each robot's discovery Service
    servers: list[Obj]  # each robot's discovery server Deployment
    policies: list[Obj]  # the fleet's NetworkPolicies
    service_of: Mapping[str, str]  # robot -> the name of its discovery Service

    def wiring(self, stored: Mapping[str, Mapping[str, Any]]) -> RosWiring:
        """What the modules are rendered with, from the Services as the cluster stores them
        (name -> Service: their cluster IPs)."""
        servers = {robot: service_address(stored[name]) for robot, name in self.service_of.items()}
        return RosWiring(self.settings, servers)


def ros_objects(
    settings: RosSettings,
    problem: Problem,
    owner: Owner | None,
    fleet_labels: Mapping[str, str],
    modules: Iterable[SoftwareModule] = (),
) -> RosObjects | None:
    """The fleet's wiring objects; None when the fleet turns its ROS wiring off."""
    if not settings.enabled:
        return None
    refs = owner_references(owner)
    labels = {**fleet_labels, LABEL_MANAGED_BY: MANAGER}
    services: list[Obj] = []
    servers: list[Obj] = []
    service_of: dict[str, str] = {}
    for robot, service, deployment in discovery_servers(problem, settings, labels, refs):
        services.append(with_spec_hash(service))
        servers.append(with_spec_hash(deployment))
        service_of[robot] = service["metadata"]["name"]
    policies = fleet_network_policies(
        fleet=problem.fleet,
        namespace=problem.namespace,
        selector=dict(fleet_labels),
        robots=sorted({inst.robot for inst in problem.instances}),
        metrics_ports=sorted({p for m in modules for p in m.spec.template.metrics_ports()}),
        owner_refs=refs,
    )
    hashed = [with_spec_hash(p) for p in policies]
    return RosObjects(settings, services, servers, hashed, service_of)
