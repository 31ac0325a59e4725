"""The apply steps, through the one apply engine (``engine.sync``): ``apply_services`` (the
discovery Services first: their cluster IPs go into every module's ``ROS_DISCOVERY_SERVER``,
``render.wiring``) and ``apply_step`` (the discovery servers, the NetworkPolicies, then the
modules' Deployments, at the site or, for a node that stands for a managed cluster, as
ManifestWorks on the OCM hub (``clusters``), keeping what a node that is down still runs).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fogfleet.api.labels import ANNOTATION_ROBOT, ANNOTATION_ROLE
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.clusters import split_remote, sync_remote
from fogfleet.controllers.fleet.engine import Kind, sync
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import ROLE_STANDBY, identity_of
from fogfleet.render.manifestwork import managed_cluster_of
from fogfleet.render.ros import RosWiring
from fogfleet.render.wiring import RosObjects, is_ros_object

__all__ = ["apply_services", "apply_step"]

Obj = dict[str, Any]


def _standby_of(deployment: Obj, robots: set[str]) -> bool:
    """Whether ``deployment`` is the on-board standby of one of ``robots``."""
    ann = (deployment.get("metadata") or {}).get("annotations") or {}
    return ann.get(ANNOTATION_ROLE) == ROLE_STANDBY and ann.get(ANNOTATION_ROBOT) in robots


def _has_cluster_ip(service: Mapping[str, Any]) -> bool:
    return bool((service.get("spec") or {}).get("clusterIP"))


def apply_services(
    deps: Deps, namespace: str, selector: Mapping[str, str], objects: RosObjects | None
) -> RosWiring | None:
    """The robots' discovery Services, applied first (stale ones deleted): the wiring the
    modules are rendered with (None: the fleet has no ROS wiring)."""
    if objects is None:
        return None
    kube = deps.kube
    services = Kind(kube.apply_service, kube.delete_service, complete=_has_cluster_ip)
    there = [s for s in kube.list_services(namespace, selector) if is_ros_object(s)]
    synced = sync(services, namespace, objects.services, there, deps.api_concurrency)
    return objects.wiring(synced.stored)


def apply_step(
    deps: Deps,
    namespace: str,
    fleet: str,
    desired: list[Obj],
    listed: list[Obj],
    problem: Problem,
    stranded: frozenset[int],
    objects: RosObjects | None,
    selector: Mapping[str, str],
    clusters: Mapping[str, str],
    hub_error: str = "",
) -> tuple[int, int]:
    """Apply the fleet's discovery servers and NetworkPolicies (``objects``; ``selector``
    picks the fleet's own policies, the only ones pruned), then its modules' Deployments
    (``desired``) against ``listed`` (the fleet's Deployments, those in managed clusters read
    back from the hub): at the site, or as ManifestWorks for those bound to a node that
    stands for a managed cluster (``clusters``: node -> cluster; none written while the hub
    does not answer, ``hub_error``); count what changed of the modules' (applied, pruned)."""
    kube, n = deps.kube, deps.api_concurrency
    deployments = Kind(kube.apply_deployment, kube.delete_deployment)
    if objects is not None:
        servers = [d for d in listed if is_ros_object(d)]
        sync(deployments, namespace, objects.servers, servers, n)
        policies = Kind(kube.apply_network_policy, kube.delete_network_policy)
        there = kube.list_network_policies(namespace, selector)
        sync(policies, namespace, objects.policies, there, n)
    idents = {
        (problem.instances[i].robot, problem.instances[i].module, problem.instances[i].replica)
        for i in stranded
    }
    # stranded instances keep their Deployment until their node returns, and so do the
    # on-board standbys of a robot that is down (cut off, they may be serving right now)
    down = {problem.instances[i].robot for i in stranded} - {""}

    def kept(dep: Obj) -> bool:
        return identity_of(dep) in idents or _standby_of(dep, down)

    modules = [d for d in listed if not is_ros_object(d)]
    here, remote = split_remote(desired, clusters)
    there = [d for d in modules if managed_cluster_of(d)]
    at_site = [d for d in modules if not managed_cluster_of(d)]
    synced = sync(deployments, namespace, here, at_site, n, kept)
    far = sync_remote(deps, namespace, remote, there, kept, hub_error)
    applied, pruned = synced.applied + far[0], synced.pruned + far[1]
    if applied or pruned:
        deps.metrics.count_apply(fleet, applied, pruned)
    return applied, pruned
