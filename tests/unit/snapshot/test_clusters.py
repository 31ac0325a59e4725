"""A ComputeNode that stands for a ManagedCluster, as the Node planning reads (issue 47)."""

from __future__ import annotations

from typing import Any

from fogfleet.snapshot.clusters import cluster_node, cluster_nodes, managed_clusters_of
from fogfleet.snapshot.objects import node_health


def _managed(status: str = "True", accepted: bool = True) -> dict[str, Any]:
    return {
        "metadata": {"name": "cloud"},
        "spec": {"hubAcceptsClient": accepted},
        "status": {
            "conditions": [
                {
                    "type": "ManagedClusterConditionAvailable",
                    "status": status,
                    "reason": "ManagedClusterLeaseUpdateStopped",
                }
            ],
            "allocatable": {"cpu": "32", "memory": "64Gi"},
        },
    }


def test_an_available_cluster_is_a_ready_node_with_its_allocatable() -> None:
    node = cluster_node("cloud-1", "cloud", _managed(), "")
    assert node_health(node) == ""
    assert node["status"]["allocatable"] == {"cpu": "32", "memory": "64Gi"}


def test_every_other_state_is_a_node_that_cannot_run_pods_and_says_why() -> None:
    assert "ManagedClusterLeaseUpdateStopped" in node_health(
        cluster_node("c", "cloud", _managed("Unknown"), "")
    )
    assert "NotAccepted" in node_health(cluster_node("c", "cloud", _managed(accepted=False), ""))
    assert "ManagedClusterMissing" in node_health(cluster_node("c", "cloud", None, ""))
    assert "HubUnreachable" in node_health(cluster_node("c", "cloud", _managed(), "timed out"))


def test_only_computenodes_with_a_managed_cluster_get_such_a_node() -> None:
    cns = [
        {"metadata": {"name": "edge-1"}, "spec": {"tier": "edge"}},
        {"metadata": {"name": "cloud-1"}, "spec": {"tier": "cloud", "managedCluster": "cloud"}},
    ]
    assert managed_clusters_of(cns) == {"cloud-1": "cloud"}
    assert [n["metadata"]["name"] for n in cluster_nodes(cns, {"cloud": _managed()}, "")] == [
        "cloud-1"
    ]
