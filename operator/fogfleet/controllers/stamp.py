"""What a fleet's last full reconcile was computed from, so the next one can tell whether only
the rollout moved (pods started, Deployments became available) and refresh the status alone.

A full reconcile builds the problem, renders and applies every Deployment: O(instances x nodes)
of Python, ~0.6 s at 400 pods and tens of seconds at 8000. While a fleet rolls out, its pods and
Deployments trigger a reconcile every debounce; all of them would redo that work only to read
which pods run. The :func:`input_stamp` covers every input of the full path that the watch
caches show - the fleet's generation, its SoftwareModules (generation, the autoscaler's pools),
the ComputeNodes, each Node's health and allocatable, each fleet Deployment's spec hash and
bound nodes - but no Deployment or Pod status. Equal stamps: the status refresh reuses the
rendered Deployments (``deps.Rendered``); any change: the full path runs. Objects the stamp
does not see (a Service or NetworkPolicy edited by hand) are repaired by a full reconcile
once the last one is old (:func:`resync_overdue`): older than ``Deps.full_reconcile_seconds``
(a minute) or ``RESYNC_COST_FACTOR`` times what it took, whichever is longer - a 1000-robot
fleet's full pass takes 12-20 s here, and re-rendering it every minute spent a quarter of a
core on it. A fleet still rolling out puts the re-render off, by up to
``RESYNC_MAX_DEFER_SECONDS``: the status refresh runs first, and the re-render only once it
finds every module running (a re-render that began just before the last pod ran held the
fleet's Ready back by its whole length: the 14.7 s Ready lag at 1000 robots).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.render.deployments import hash_annotation
from fogfleet.snapshot.clusters import ANNOTATION_CLAIMS
from fogfleet.snapshot.objects import bound_nodes, node_health, scaling_status

__all__ = [
    "RESYNC_COST_FACTOR",
    "RESYNC_MAX_DEFER_SECONDS",
    "DeploymentStamps",
    "input_stamp",
    "node_signature",
    "pools_signature",
    "resync_overdue",
]

Obj = dict[str, Any]
RESYNC_COST_FACTOR = 10.0  # at most about a tenth of the time goes to re-rendering unchanged fleets
RESYNC_MAX_DEFER_SECONDS = 600.0  # a rollout that never ends does not put the re-render off longer


def resync_overdue(at: float, took: float, period: float, now: float | None = None) -> float | None:
    """Seconds by which a render made at ``at`` (``time.monotonic()``) that took ``took``
    seconds is past due for a re-render, or None while it is not due; ``period`` 0 makes
    every render due at once."""
    due = at + (max(period, RESYNC_COST_FACTOR * took) if period > 0 else 0.0)
    overdue = (time.monotonic() if now is None else now) - due
    return overdue if overdue >= 0 else None


def _meta(obj: Mapping[str, Any]) -> Mapping[str, Any]:
    return obj.get("metadata") or {}


def pools_signature(module: Mapping[str, Any]) -> tuple[Any, ...]:
    """The autoscaler's decision for a module (status.scaling.pools): it changes what fleets
    place, though not the module's generation."""
    scaling = scaling_status(module)
    return tuple(sorted((p.tier, p.replicas) for p in (scaling.pools if scaling else [])))


def node_signature(node: Mapping[str, Any]) -> tuple[Any, ...]:
    """What of a Node planning reads: its health and allocatable CPU, memory and GPUs (and
    of a managed cluster's, its claims: ``snapshot.clusters``)."""
    alloc = (node.get("status") or {}).get("allocatable") or {}
    return (
        node_health(node),
        alloc.get("cpu"),
        alloc.get("memory"),
        alloc.get("nvidia.com/gpu"),
        ((node.get("metadata") or {}).get("annotations") or {}).get(ANNOTATION_CLAIMS),
    )


def _deployment(dep: Mapping[str, Any]) -> tuple[Any, ...]:
    meta = _meta(dep)
    return (
        meta.get("name"),
        hash_annotation(dep),
        tuple(bound_nodes(dep)),
        bool(meta.get("deletionTimestamp")),
    )


class DeploymentStamps:
    """The Deployments' part of a fleet's stamp, remembered between reconciles for the objects
    listed again as the same object.

    The watch caches replace a cached object on every event and never change one in place
    (adapters/informer.py: readers treat the dicts as read-only), so an object listed again
    is unchanged and its part of the stamp too; a list from the API server (no watch cache) is
    all new objects and costs what it always did. At 1000 robots this part was half of a
    status refresh: 9000 Deployments read again at every refresh (0.15-0.35 s of the 0.3-0.5 s
    on a quiet machine)."""

    def __init__(self) -> None:
        self._seen: dict[int, tuple[Mapping[str, Any], tuple[Any, ...]]] = {}
        self._last: tuple[Any, ...] | None = None

    def __call__(self, deployments: Iterable[Mapping[str, Any]]) -> tuple[Any, ...]:
        seen: dict[int, tuple[Mapping[str, Any], tuple[Any, ...]]] = {}
        fresh = 0
        for dep in deployments:
            hit = self._seen.get(id(dep))
            if hit is None or hit[0] is not dep:
                hit = (dep, _deployment(dep))
                fresh += 1
            seen[id(dep)] = hit
        if fresh or self._last is None or len(seen) != len(self._seen):
            self._last = tuple(sorted(sig for _, sig in seen.values()))
        self._seen = seen
        return self._last


def input_stamp(
    fleet: Mapping[str, Any],
    modules: Iterable[Mapping[str, Any]],
    compute_nodes: Iterable[Mapping[str, Any]],
    nodes: Iterable[Mapping[str, Any]],
    deployments: Iterable[Mapping[str, Any]],
    deployment_stamps: DeploymentStamps,
) -> tuple[Any, ...]:
    """Everything the full reconcile reads, without the rollout's progress (hashable);
    ``deployment_stamps``: the fleet's, which remembers the Deployments' part."""
    meta = _meta(fleet)
    return (
        meta.get("uid"),
        meta.get("generation"),
        tuple(
            sorted(
                (
                    _meta(m).get("name"),
                    _meta(m).get("uid"),
                    _meta(m).get("generation"),
                    pools_signature(m),
                )
                for m in modules
            )
        ),
        tuple(
            sorted(
                (_meta(c).get("name"), _meta(c).get("uid"), _meta(c).get("generation"))
                for c in compute_nodes
            )
        ),
        tuple(sorted((_meta(n).get("name"), *node_signature(n)) for n in nodes)),
        deployment_stamps(deployments),
    )
