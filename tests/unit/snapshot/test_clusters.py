"""A ComputeNode that stands for a ManagedCluster, as the Node planning reads (issue 47)."""

from __future__ import annotations

from typing import Any

from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.snapshot.clusters import cluster_node, cluster_nodes, managed_clusters_of, with_claims
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


def _cloud(**spec: Any) -> ComputeNode:
    body = {"tier": "cloud", "hardwareType": "vm", "managedCluster": "cloud", **spec}
    return ComputeNode.model_validate({"metadata": {"name": "cloud-1"}, "spec": body})


def _claimed(**claims: str) -> dict[str, Any]:
    managed = _managed()
    managed["status"]["clusterClaims"] = [
        {"name": "id.k8s.io", "value": "x"},
        *({"name": k, "value": v} for k, v in claims.items()),
    ]
    return cluster_node("cloud-1", "cloud", managed, "")


CLAIMED = {
    "privacy-level.fogfleet.io": "1",
    "cost-per-core-hour.fogfleet.io": "0.04",
    "wan-latency-millis.fogfleet.io": "15.5",
    "wan-bandwidth-mbps.fogfleet.io": "100",
}


def test_the_clusters_claims_fill_what_the_computenode_leaves_out() -> None:
    cn = with_claims(_cloud(), _claimed(**CLAIMED))
    assert cn.spec.privacy == 1 and float(cn.spec.cost_per_core_hour) == 0.04
    link = cn.spec.network[0]
    assert (link.type, float(link.latency_millis), float(link.bandwidth_mbps)) == ("wan", 15.5, 100)


def test_what_the_computenode_says_wins_over_the_claims() -> None:
    own = {"type": "wan", "latencyMillis": 30, "bandwidthMbps": 10}
    cn = with_claims(_cloud(privacyLevel=0, costPerCoreHour=1, network=[own]), _claimed(**CLAIMED))
    assert cn.spec.privacy == 0 and float(cn.spec.cost_per_core_hour) == 1
    assert float(cn.spec.network[0].latency_millis) == 30


def test_a_claim_that_makes_no_valid_spec_is_ignored() -> None:
    cn = with_claims(_cloud(), _claimed(**{"privacy-level.fogfleet.io": "9"}))
    assert cn.spec.privacy_level is None
