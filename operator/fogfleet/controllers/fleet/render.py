"""The render steps, pure: the fleet's ROS 2 wiring objects (``wiring_step``) and its modules'
Deployments from its decision (``render_step``), given the wiring as applied (the discovery
Services' cluster IPs go into every module's ``ROS_DISCOVERY_SERVER``).

The wiring is rendered after planning: an infeasible fleet gets nothing applied, not even its
discovery servers.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from fogfleet.api.labels import LABEL_MANAGED_BY, MANAGER
from fogfleet.controllers.fleet.clusters import split_remote
from fogfleet.controllers.fleet.observe import FleetInputs, Parsed
from fogfleet.controllers.fleet.plan import Planned
from fogfleet.domain.fallback import fleet_fallbacks
from fogfleet.render.deployments import owner_references, render_fleet, with_spec_hash
from fogfleet.render.relays import relay_network_policy, site_relays, with_relay
from fogfleet.render.ros import RosWiring
from fogfleet.render.wiring import RosObjects, ros_objects
from fogfleet.snapshot.clusters import managed_clusters_of, relay_routers

__all__ = ["relay_step", "render_step", "wiring_step"]

Obj = dict[str, Any]


def wiring_step(inputs: FleetInputs, parsed: Parsed, planned: Planned) -> RosObjects | None:
    """The fleet's discovery servers and NetworkPolicies (None: its ROS wiring is off)."""
    obj = inputs.obj
    return ros_objects(
        inputs.fleet.spec.ros,
        planned.problem,
        obj.owner,
        obj.selector,
        parsed.modules.values(),
    )


def render_step(
    inputs: FleetInputs, parsed: Parsed, planned: Planned, wiring: RosWiring | None
) -> list[Obj]:
    """The Deployments the fleet's modules should have (instance order)."""
    fleet, obj, problem = inputs.fleet, inputs.obj, planned.problem
    modules = parsed.modules
    decision = planned.decision
    if decision is None:
        return render_fleet(problem, modules, None, baseline=True, owner=obj.owner, wiring=wiring)
    return render_fleet(
        problem,
        modules,
        decision.placement,
        with_limits=decision.schedule.with_limits,
        cpu_limit_percent=fleet.spec.scheduler.cpu_limit_percent,
        fallbacks=fleet_fallbacks(fleet.spec, modules),
        owner=obj.owner,
        plan_id=decision.plan_id,
        wiring=wiring,
    )


def relay_step(
    inputs: FleetInputs,
    planned: Planned,
    objects: RosObjects | None,
    wiring: RosWiring | None,
    desired: list[Obj],
    site_router: str,
) -> tuple[RosObjects | None, list[Obj]]:
    """The plan's cut edges across the WAN (``render.relays``): the instances bound for managed
    clusters with their relay sidecars (``desired``, in its order), and each robot's relay at
    the site among the wiring objects (``site_router``: what they dial; "": none)."""
    clusters = managed_clusters_of(inputs.compute_nodes)
    if objects is None or wiring is None or not clusters:
        return objects, desired
    _, remote = split_remote(desired, clusters)
    routers = relay_routers(inputs.nodes)
    image = objects.settings.discovery_server_image
    sent = {
        id(d): with_spec_hash(with_relay(d, routers.get(cluster), image))
        for cluster, deployments in remote.items()
        for d in deployments
    }
    if not sent:
        return objects, desired
    problem, obj = planned.problem, inputs.obj
    nodes = {n.name: n.node_name for n in problem.nodes}
    robots = {i.robot for i in problem.instances if i.robot in nodes}
    meta = {
        "fleet": problem.fleet,
        "namespace": problem.namespace,
        "labels": {**obj.selector, LABEL_MANAGED_BY: MANAGER},
        "ownerReferences": owner_references(obj.owner),
    }
    far = [d for deployments in remote.values() for d in deployments]
    relays = site_relays(far, wiring, {r: nodes[r] for r in robots}, site_router, meta)
    desired = [sent.get(id(d), d) for d in desired]
    if not relays:
        return objects, desired
    servers = [*objects.servers, *map(with_spec_hash, relays)]
    policy = with_spec_hash(relay_network_policy(site_router, meta))
    return replace(objects, servers=servers, policies=[*objects.policies, policy]), desired
