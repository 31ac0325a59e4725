"""The managed clusters a site plans into, as the Nodes planning reads (issue 47).

A ComputeNode with ``spec.managedCluster`` stands for an Open Cluster Management
ManagedCluster: a cloud of its own, reached over the WAN. Planning reads a node's health and
allocatable resources from its Kubernetes Node (``objects.node_health``, ``catalog.gather``);
for such a ComputeNode there is none at the site, so ``cluster_nodes`` makes one from what the
hub says of the cluster: Ready while the ManagedCluster is accepted and Available (its agent
renews its lease; OCM's ``ManagedClusterConditionAvailable``), allocatable what the agent
reports of the cluster's nodes (``status.allocatable``). When the hub cannot be read the node
is NotReady, with why: the instances placed there are then stranded, kept and not moved back
until the cluster returns (``controllers.fleet.apply``), as on a Node that stops reporting.

What the ComputeNode leaves out, the cluster may say of itself with OCM ClusterClaims (created
on the managed cluster, reported in ``ManagedCluster.status.clusterClaims``): its privacy level
and price (tinyKube's cloud: privacy 0, a price per core) and its WAN link (``CLAIMS``).
``with_claims`` fills them in; what the ComputeNode says wins.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Collection, Iterable, Mapping
from typing import Any

from pydantic import ValidationError

from fogfleet.api.labels import ANNOTATION_MANAGED_CLUSTER
from fogfleet.api.v1alpha1.computenode import ComputeNode, ComputeNodeSpec
from fogfleet.api.v1alpha1.placement import placement_entries_of

__all__ = [
    "ANNOTATION_CLAIMS",
    "AVAILABLE",
    "CLAIMS",
    "ROUTER_CLAIM",
    "cluster_node",
    "cluster_nodes",
    "managed_clusters_of",
    "placed_in",
    "relay_routers",
    "with_claims",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
AVAILABLE = "ManagedClusterConditionAvailable"
# ClusterClaim -> what it fills in a ComputeNode's spec that leaves it out
CLAIMS = {
    "privacy-level.fogfleet.io": "privacyLevel",
    "cost-per-core-hour.fogfleet.io": "costPerCoreHour",
    "wan-latency-millis.fogfleet.io": "latencyMillis",
    "wan-bandwidth-mbps.fogfleet.io": "bandwidthMbps",
}
ANNOTATION_CLAIMS = "fogfleet.io/cluster-claims"  # on the Node made here: the claims (JSON)
# ClusterClaim: the Zenoh router of the cluster that the relays beside its instances dial
# (render.relays; a Zenoh endpoint such as tcp/zenoh-router.fogfleet-system:7447)
ROUTER_CLAIM = "relay-router.fogfleet.io"


def managed_clusters_of(compute_nodes: Iterable[Mapping[str, Any]]) -> dict[str, str]:
    """ComputeNode name -> the ManagedCluster it stands for (raw objects, unvalidated)."""
    return {_name(cn): cluster for cn in compute_nodes if (cluster := _cluster_of(cn))}


def _name(compute_node: Mapping[str, Any]) -> str:
    return str((compute_node.get("metadata") or {}).get("name", ""))


def _cluster_of(compute_node: Mapping[str, Any]) -> str | None:
    """The ManagedCluster a raw ComputeNode stands for (None: it is a Node of the site)."""
    cluster = (compute_node.get("spec") or {}).get("managedCluster")
    return cluster if isinstance(cluster, str) and cluster else None


def _ready(status: str, reason: str, message: str) -> Obj:
    return {"type": "Ready", "status": status, "reason": reason, "message": message}


def cluster_node(name: str, cluster: str, managed: Mapping[str, Any] | None, hub_error: str) -> Obj:
    """The Node planning reads for ComputeNode ``name`` standing for ManagedCluster
    ``cluster`` (``managed``: as the hub has it; ``hub_error``: why the hub was not read)."""
    if hub_error:
        ready = _ready("Unknown", "HubUnreachable", hub_error)
    elif managed is None:
        ready = _ready("False", "ManagedClusterMissing", f"no ManagedCluster {cluster} on the hub")
    elif not (managed.get("spec") or {}).get("hubAcceptsClient"):
        ready = _ready("False", "NotAccepted", f"the hub has not accepted {cluster}")
    else:
        conds = {c.get("type"): c for c in (managed.get("status") or {}).get("conditions") or []}
        available = conds.get(AVAILABLE) or {}
        status = str(available.get("status") or "Unknown")
        reason = str(available.get("reason") or "NotReported")
        ready = _ready(
            "True" if status == "True" else status, reason, str(available.get("message") or "")
        )
    alloc = ((managed or {}).get("status") or {}).get("allocatable") or {}
    claims = {
        str(c.get("name")): str(c.get("value"))
        for c in ((managed or {}).get("status") or {}).get("clusterClaims") or []
        if c.get("name") in CLAIMS or c.get("name") == ROUTER_CLAIM
    }
    annotations = {ANNOTATION_MANAGED_CLUSTER: cluster}
    if claims:
        annotations[ANNOTATION_CLAIMS] = json.dumps(claims, sort_keys=True)
    return {
        "apiVersion": "v1",
        "kind": "Node",
        "metadata": {"name": name, "annotations": annotations},
        "status": {"conditions": [ready], "allocatable": dict(alloc), "capacity": dict(alloc)},
    }


def relay_routers(nodes: Iterable[Mapping[str, Any]]) -> dict[str, str]:
    """Managed cluster -> the Zenoh router its ClusterClaim ``ROUTER_CLAIM`` names, from the
    Nodes made here (``cluster_node``); a cluster that claims none is left out."""
    out = {}
    for node in nodes:
        annotations = (node.get("metadata") or {}).get("annotations") or {}
        cluster = annotations.get(ANNOTATION_MANAGED_CLUSTER)
        router = json.loads(annotations.get(ANNOTATION_CLAIMS) or "{}").get(ROUTER_CLAIM)
        if cluster and router:
            out[str(cluster)] = str(router)
    return out


def _recorded(compute_node: Mapping[str, Any]) -> Obj | None:
    """A ManagedCluster as the ComputeNode's status last recorded it (its allocatable): what
    an operator that has not read the hub since it started knows of the cluster."""
    status = compute_node.get("status") or {}
    cpu, memory = status.get("allocatableCpu"), status.get("allocatableMemory")
    return {"status": {"allocatable": {"cpu": cpu, "memory": memory}}} if cpu and memory else None


def cluster_nodes(
    compute_nodes: Iterable[Mapping[str, Any]],
    managed: Mapping[str, Mapping[str, Any]],
    hub_error: str,
) -> list[Obj]:
    """A Node for every ComputeNode that stands for a managed cluster (``managed``: the hub's
    ManagedClusters by name; when the hub did not answer and one was never read, what the
    ComputeNode's status recorded of it)."""
    out = []
    for cn in sorted(compute_nodes, key=_name):
        cluster = _cluster_of(cn)
        if cluster is not None:
            known = managed.get(cluster) or (_recorded(cn) if hub_error else None)
            out.append(cluster_node(_name(cn), cluster, known, hub_error))
    return out


def placed_in(status: Mapping[str, Any], nodes: Collection[str]) -> dict[tuple[str, str, int], str]:
    """(robot, module, replica) -> node of a fleet's placement entries on ``nodes`` (its
    status.placement or placementCompact): where the fleet last said its instances run in the
    clusters (an operator that cannot read the hub's works plans with it, so as to start none
    of them a second time at the site)."""
    out: dict[tuple[str, str, int], str] = {}
    for entry in placement_entries_of(status):
        node = entry.get("node")
        if node in nodes:
            ident = (
                str(entry.get("robot") or ""),
                str(entry["module"]),
                int(entry.get("replica") or 0),
            )
            out[ident] = str(node)
    return out


def _number(text: str) -> int | float | str:
    """A claim's value (text) as the number it says, else as it is (refused by the spec)."""
    try:
        value = float(text)
    except ValueError:
        return text
    return int(value) if value.is_integer() else value


def with_claims(cn: ComputeNode, node: Mapping[str, Any] | None) -> ComputeNode:
    """``cn`` with what its cluster's claims say where its spec says nothing (``CLAIMS``): the
    privacy level, the price per core-hour, and a WAN uplink of the claimed latency and
    bandwidth when it has no uplink. A claim that does not make a valid spec is ignored."""
    annotations = ((node or {}).get("metadata") or {}).get("annotations") or {}
    if not cn.spec.managed_cluster or ANNOTATION_CLAIMS not in annotations:
        return cn
    said = json.loads(annotations[ANNOTATION_CLAIMS]).items()
    claims = {CLAIMS[k]: _number(v) for k, v in said if k in CLAIMS}
    spec = cn.spec.model_dump(by_alias=True, exclude_unset=True, mode="json")
    for field in ("privacyLevel", "costPerCoreHour"):
        if field in claims and field not in spec:
            spec[field] = claims[field]
    if not cn.spec.network and {"latencyMillis", "bandwidthMbps"} <= claims.keys():
        link = {k: claims[k] for k in ("latencyMillis", "bandwidthMbps")}
        spec["network"] = [{"type": "wan", **link}]
    try:
        filled = ComputeNodeSpec.model_validate(spec)
    except ValidationError as exc:
        log.warning("ComputeNode %s: ignoring its cluster's claims %s: %s",
                    cn.metadata.name, claims, exc.errors()[0].get("msg"))  # fmt: skip
        return cn
    return cn.model_copy(update={"spec": filled})
