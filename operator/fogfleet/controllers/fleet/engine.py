"""The one apply engine: every object the fleet's reconcile writes (the modules' Deployments,
the robots' discovery Services and Deployments, the fleet's NetworkPolicies, the ManifestWorks
of its instances in managed clusters) goes through ``sync``: compare spec hashes, server-side
apply what changed, prune what is no longer wanted, in parallel (``controllers.parallel``).
The steps that call it: ``apply`` (the site) and ``clusters`` (the OCM hub).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.controllers.parallel import run_all
from fogfleet.render.deployments import hash_annotation

__all__ = ["Kind", "Synced", "owned", "sync"]

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
