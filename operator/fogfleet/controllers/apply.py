"""Apply a fleet's rendered Deployments: server-side apply what changed, delete what is
stale, in parallel (``controllers.parallel``), and keep what a node that is down still runs."""

from __future__ import annotations

import functools
from typing import Any

from fogfleet.api.labels import ANNOTATION_ROBOT, ANNOTATION_ROLE
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import ROLE_STANDBY, hash_annotation, identity_of

from .deps import Deps
from .parallel import run_all

__all__ = ["apply_fleet", "apply_step", "owned"]

Obj = dict[str, Any]


def owned(dep: Obj, uid: str | None) -> bool:
    """Whether the fleet of ``uid`` owns ``dep`` (or either says nothing)."""
    refs = (dep.get("metadata") or {}).get("ownerReferences") or []
    return not uid or not refs or any(r.get("uid") == uid for r in refs)


def _standby_of(deployment: Obj, robots: set[str]) -> bool:
    """Whether ``deployment`` is the on-board standby of one of ``robots``."""
    ann = (deployment.get("metadata") or {}).get("annotations") or {}
    return ann.get(ANNOTATION_ROLE) == ROLE_STANDBY and ann.get(ANNOTATION_ROBOT) in robots


def apply_fleet(
    deps: Deps,
    ns: str,
    desired: list[Obj],
    deployments: list[Obj],
    problem: Problem,
    stranded: set[int],
) -> tuple[int, int]:
    have = {d["metadata"]["name"]: d for d in deployments}
    changed = [
        d for d in desired if hash_annotation(have.get(d["metadata"]["name"])) != hash_annotation(d)
    ]
    keep = {d["metadata"]["name"] for d in desired}
    idents = {
        (problem.instances[i].robot, problem.instances[i].module, problem.instances[i].replica)
        for i in stranded
    }
    # stranded instances keep their Deployment until their node returns, and so do the
    # on-board standbys of a robot that is down (cut off, they may be serving right now)
    down = {problem.instances[i].robot for i in stranded} - {""}
    stale = [
        n
        for n, d in have.items()
        if n not in keep and identity_of(d) not in idents and not _standby_of(d, down)
    ]
    kube = deps.kube
    run_all([functools.partial(kube.apply_deployment, d) for d in changed], deps.api_concurrency)
    run_all([functools.partial(kube.delete_deployment, ns, n) for n in stale], deps.api_concurrency)
    return len(changed), len(stale)


def apply_step(
    deps: Deps,
    namespace: str,
    fleet: str,
    desired: list[Obj],
    deployments: list[Obj],
    problem: Problem,
    stranded: frozenset[int],
) -> tuple[int, int]:
    """Apply the fleet's desired Deployments and count what changed (applied, pruned)."""
    applied, pruned = apply_fleet(deps, namespace, desired, deployments, problem, set(stranded))
    if applied or pruned:
        deps.metrics.count_apply(fleet, applied, pruned)
    return applied, pruned
