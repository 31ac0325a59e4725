"""A fleet's instances in managed clusters (issue 47; docs/multicluster.md): what the OCM hub
says of the clusters, and the fleet's ManifestWorks there.

``hub_nodes`` gives planning a Node for every ComputeNode that stands for a managed cluster
(``snapshot.clusters``). ``remote_deployments`` reads the fleet's works back as Deployments
(``render.manifestwork.deployment_of``): with them in the fleet's list, the current placement,
the stamp, the status and the apply engine treat a remote instance as a local one.
``sync_remote`` is the apply engine's pass over them: one ManifestWork per instance planned
into a cluster, written with server-side apply on the hub, stale ones deleted.

The hub may be across the WAN. When it cannot be read the fleet goes on at the site: the
clusters' nodes are NotReady (the instances there stranded, so kept), the fleet's remote
Deployments are the ones last read, and nothing is written to the hub until it answers again.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from fogfleet.api.labels import LABEL_FLEET, LABEL_SITE_NAMESPACE
from fogfleet.api.timestamps import parse_timestamp
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.engine import Kind, sync
from fogfleet.controllers.state import FleetState
from fogfleet.errors import DependencyUnavailable
from fogfleet.render.deployments import label_value
from fogfleet.render.manifestwork import deployment_of, managed_cluster_of, work_of, work_selector
from fogfleet.render.names import work_name
from fogfleet.snapshot.clusters import cluster_nodes, managed_clusters_of
from fogfleet.snapshot.objects import bound_nodes, fleet_key

__all__ = [
    "ORPHAN_GRACE_SECONDS",
    "delete_remote",
    "hub_nodes",
    "remote_deployments",
    "split_remote",
    "sweep_orphans",
    "sync_remote",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
NO_HUB = "the operator has no OCM hub (FOGFLEET_HUB_KUBECONFIG is not set)"
# a work younger than this is never swept: its fleet may be newer than the list of fleets
ORPHAN_GRACE_SECONDS = 120.0


def hub_nodes(deps: Deps, compute_nodes: Iterable[Mapping[str, Any]]) -> tuple[list[Obj], str]:
    """A Node for each ComputeNode that stands for a managed cluster, and why the hub was not
    read ("" when it was, or when no ComputeNode needs it). A cluster the hub cannot be asked
    about keeps the allocatable last read: its instances are stranded where they run."""
    compute_nodes = list(compute_nodes)
    if not managed_clusters_of(compute_nodes):
        return [], ""
    if deps.hub is None:
        return cluster_nodes(compute_nodes, {}, NO_HUB), NO_HUB
    hub, error = deps.hub, ""
    try:
        managed = {str(mc["metadata"]["name"]): mc for mc in hub.port.list_managed_clusters()}
        hub.seen.update(managed)  # never empty meanwhile: other fleets' passes read it
        for gone in set(hub.seen) - set(managed):
            hub.seen.pop(gone, None)
    except DependencyUnavailable as exc:
        error = str(exc)
    return cluster_nodes(compute_nodes, dict(hub.seen), error), error


def remote_deployments(
    deps: Deps,
    state: FleetState,
    compute_nodes: Iterable[Mapping[str, Any]],
    namespace: str,
    fleet_label: str,
    hub_error: str = "",
) -> tuple[list[Obj], str]:
    """The fleet's Deployments in managed clusters, read back from its works on the hub (the
    last ones read, when the hub does not answer or did not this pass, ``hub_error``), and why
    the hub was not read."""
    clusters = sorted(set(managed_clusters_of(compute_nodes).values()))
    if deps.hub is None:
        return [], NO_HUB if clusters else ""
    if hub_error:
        return state.remote, hub_error
    hub = deps.hub
    clusters = sorted(set(clusters) | {c for d in state.remote if (c := managed_cluster_of(d))})
    selector = work_selector(hub.site, namespace, fleet_label)
    found: list[Obj] = []
    try:
        for cluster in clusters:
            found += [d for w in hub.port.list_works(cluster, selector) if (d := deployment_of(w))]
    except DependencyUnavailable as exc:
        return state.remote, str(exc)
    state.remote = found
    return found, ""


def split_remote(
    deployments: Iterable[Obj], clusters: Mapping[str, str]
) -> tuple[list[Obj], dict[str, list[Obj]]]:
    """``deployments`` (rendered for the site) as those that stay at the site and, by managed
    cluster, those bound to a ComputeNode that stands for one (``clusters``: node -> cluster)."""
    local: list[Obj] = []
    remote: dict[str, list[Obj]] = {}
    for dep in deployments:
        nodes = bound_nodes(dep)
        cluster = clusters.get(nodes[0]) if len(nodes) == 1 else None
        if cluster is None:
            local.append(dep)
        else:
            remote.setdefault(cluster, []).append(dep)
    return local, remote


def sync_remote(
    deps: Deps,
    namespace: str,
    desired: Mapping[str, list[Obj]],
    there: Iterable[Obj],
    keep: Callable[[Obj], bool],
    hub_error: str,
) -> tuple[int, int]:
    """Write the fleet's works (``desired``: its Deployments by managed cluster) on the hub,
    and delete those of ``there`` (read back) no longer desired, unless ``keep``; (applied,
    pruned). Nothing is written while the hub does not answer (``hub_error``)."""
    there = list(there)
    if deps.hub is None or (not desired and not there):
        return 0, 0
    if hub_error:
        log.info("Not writing %d ManifestWorks of %s: %s", len(there), namespace, hub_error)
        return 0, 0
    hub = deps.hub
    where = {str(d["metadata"]["name"]): managed_cluster_of(d) or "" for d in there}
    for cluster, deployments in desired.items():
        where.update((str(d["metadata"]["name"]), cluster) for d in deployments)

    def apply(body: Obj) -> Obj:
        work = hub.port.apply_work(work_of(body, where[str(body["metadata"]["name"])], hub.site))
        return deployment_of(work) or body

    def delete(ns: str, name: str) -> None:
        hub.port.delete_work(where[name], work_name(hub.site, ns, name))

    wanted = [d for deployments in desired.values() for d in deployments]
    kind = Kind(apply, delete)
    synced = sync(kind, namespace, wanted, there, deps.api_concurrency, keep=keep)
    return synced.applied, synced.pruned


def delete_remote(deps: Deps, namespace: str, fleet_label: str) -> int:
    """Delete the works of a fleet that is gone, in every managed cluster a ComputeNode stands
    for (their Deployments go from those clusters with them); how many."""
    if deps.hub is None:
        return 0
    hub = deps.hub
    clusters = sorted(set(managed_clusters_of(deps.kube.list_compute_nodes()).values()))
    selector = work_selector(hub.site, namespace, fleet_label)
    gone = 0
    for cluster in clusters:
        for work in hub.port.list_works(cluster, selector):
            hub.port.delete_work(cluster, str(work["metadata"]["name"]))
            gone += 1
    return gone


def sweep_orphans(deps: Deps, fleets: Iterable[Mapping[str, Any]], now: float) -> int:
    """Delete the works this site wrote for fleets that are gone (deleted while the operator
    was not running: nothing else deletes them), in the namespaces it serves, once older than
    ``ORPHAN_GRACE_SECONDS``; how many (``fleets``: every fleet it serves, as listed)."""
    if deps.hub is None:
        return 0
    hub = deps.hub
    live = {(namespace, label_value(name)) for namespace, name in map(fleet_key, fleets)}
    site = work_selector(hub.site)
    gone = 0
    for cluster in sorted(set(managed_clusters_of(deps.kube.list_compute_nodes()).values())):
        for work in hub.port.list_works(cluster, site):
            meta = work.get("metadata") or {}
            labels = meta.get("labels") or {}
            namespace, fleet = labels.get(LABEL_SITE_NAMESPACE), labels.get(LABEL_FLEET)
            created = parse_timestamp(meta.get("creationTimestamp"))
            if (
                not namespace
                or (hub.namespaces and namespace not in hub.namespaces)
                or (namespace, fleet) in live
                or created is None
                or now - created < ORPHAN_GRACE_SECONDS
            ):
                continue
            log.info("Deleting ManifestWork %s/%s: its RobotFleet %s/%s is gone",
                     cluster, meta.get("name"), namespace, fleet)  # fmt: skip
            hub.port.delete_work(cluster, str(meta["name"]))
            gone += 1
    return gone
