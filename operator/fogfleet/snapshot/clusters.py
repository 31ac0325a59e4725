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
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.api.labels import ANNOTATION_MANAGED_CLUSTER

__all__ = ["AVAILABLE", "cluster_node", "cluster_nodes", "managed_clusters_of"]

Obj = dict[str, Any]
AVAILABLE = "ManagedClusterConditionAvailable"


def managed_clusters_of(compute_nodes: Iterable[Mapping[str, Any]]) -> dict[str, str]:
    """ComputeNode name -> the ManagedCluster it stands for (raw objects, unvalidated)."""
    out: dict[str, str] = {}
    for cn in compute_nodes:
        cluster = (cn.get("spec") or {}).get("managedCluster")
        if isinstance(cluster, str) and cluster:
            out[str((cn.get("metadata") or {}).get("name", ""))] = cluster
    return out


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
    return {
        "apiVersion": "v1",
        "kind": "Node",
        "metadata": {"name": name, "annotations": {ANNOTATION_MANAGED_CLUSTER: cluster}},
        "status": {"conditions": [ready], "allocatable": dict(alloc), "capacity": dict(alloc)},
    }


def cluster_nodes(
    compute_nodes: Iterable[Mapping[str, Any]],
    managed: Mapping[str, Mapping[str, Any]],
    hub_error: str,
) -> list[Obj]:
    """A Node for every ComputeNode that stands for a managed cluster (``managed``: the hub's
    ManagedClusters by name)."""
    return [
        cluster_node(name, cluster, managed.get(cluster), hub_error)
        for name, cluster in sorted(managed_clusters_of(compute_nodes).items())
    ]
