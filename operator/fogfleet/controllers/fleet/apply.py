"""The one apply engine: every object the fleet's reconcile writes (the modules' Deployments,
the robots' discovery Services and Deployments, the fleet's NetworkPolicies) goes through
``sync``: compare spec hashes, server-side apply what changed, prune what is no longer
wanted, in parallel (``controllers.parallel``).

The steps: ``apply_services`` (the discovery Services first: their cluster IPs go into every
module's ``ROS_DISCOVERY_SERVER``, ``render.wiring``) and ``apply_step`` (the discovery
servers, the NetworkPolicies, then the modules' Deployments, keeping what a node that is down
still runs).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.api.labels import ANNOTATION_ROBOT, ANNOTATION_ROLE
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.parallel import run_all
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import ROLE_STANDBY, hash_annotation, identity_of
from fogfleet.render.ros import RosWiring
from fogfleet.render.wiring import RosObjects, is_ros_object

__all__ = ["Kind", "Synced", "apply_services", "apply_step", "owned", "sync"]

Obj = dict[str, Any]


@dataclass(frozen=True)
class Kind:
    """How the engine writes one kind: the API calls, and when an object there, whose spec
    hash is the wanted one, is complete (a Service once its cluster IP is allocated)."""

    apply: Callable[[Obj], Obj]
    delete: Callable[[str, str], None]
    complete: Callable[[Mapping[str, Any]], bool] = lambda _obj: True


@dataclass(frozen=True)
class Synced:
    """What ``sync`` did, and each wanted object as the cluster stores it now."""

    stored: Mapping[str, Obj]  # name -> the object there (unchanged) or as applied
    applied: int
    pruned: int


def _name(obj: Mapping[str, Any]) -> str:
    return str(obj["metadata"]["name"])


def sync(
    kind: Kind,
    namespace: str,
    desired: Iterable[Obj],
    there: Iterable[Obj],
    concurrency: int,
    keep: Callable[[Obj], bool] = lambda _obj: False,
) -> Synced:
    """Make the objects ``there`` (the fleet's, of one kind) what ``desired`` says: apply each
    desired object whose spec hash differs from the one there (or that is not complete yet),
    delete each one there that is not desired, unless ``keep`` says to leave it."""
    have = {_name(o): o for o in there}
    wanted = {_name(d): d for d in desired}
    stored: dict[str, Obj] = {}
    changed = []
    for name, body in wanted.items():
        old = have.get(name)
        if old is not None and hash_annotation(old) == hash_annotation(body) and kind.complete(old):
            stored[name] = old
        else:
            changed.append(body)

    def write(body: Obj) -> None:
        result = kind.apply(body)
        stored[_name(body)] = result if result and result.get("spec") else body

    stale = [n for n, o in have.items() if n not in wanted and not keep(o)]
    run_all([functools.partial(write, body) for body in changed], concurrency)
    run_all([functools.partial(kind.delete, namespace, n) for n in stale], concurrency)
    return Synced(stored, len(changed), len(stale))


def owned(dep: Obj, uid: str | None) -> bool:
    """Whether the fleet of ``uid`` owns ``dep`` (or either says nothing)."""
    refs = (dep.get("metadata") or {}).get("ownerReferences") or []
    return not uid or not refs or any(r.get("uid") == uid for r in refs)


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
) -> tuple[int, int]:
    """Apply the fleet's discovery servers and NetworkPolicies (``objects``; ``selector``
    picks the fleet's own policies, the only ones pruned), then its modules' Deployments
    (``desired``) against ``listed`` (the fleet's Deployments); count what changed of the
    modules' (applied, pruned)."""
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
    synced = sync(deployments, namespace, desired, modules, n, keep=kept)
    if synced.applied or synced.pruned:
        deps.metrics.count_apply(fleet, synced.applied, synced.pruned)
    return synced.applied, synced.pruned
