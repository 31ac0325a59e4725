"""A module's Deployment as a ManifestWork for a managed cluster, and back (issue 47)."""

from __future__ import annotations

import copy
from typing import Any

from fogfleet.api.labels import ANNOTATION_NODE, ANNOTATION_SPEC_HASH
from fogfleet.render.deployments import node_affinity
from fogfleet.render.manifestwork import (
    FEEDBACK,
    deployment_of,
    managed_cluster_of,
    work_of,
    work_selector,
)
from fogfleet.snapshot.objects import bound_nodes, current_placement

Obj = dict[str, Any]


def _deployment() -> Obj:
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {
            "name": "warehouse-robot-1-mapping-0123abcd",
            "namespace": "warehouse",
            "labels": {"fogfleet.io/fleet": "warehouse", "fogfleet.io/module": "mapping"},
            "annotations": {
                ANNOTATION_SPEC_HASH: "h1",
                ANNOTATION_NODE: "cloud-1",
                "fogfleet.io/robot": "robot-1",
                "fogfleet.io/module": "mapping",
                "fogfleet.io/replica": "0",
            },
            "ownerReferences": [{"kind": "RobotFleet", "name": "warehouse", "uid": "u1"}],
        },
        "spec": {
            "replicas": 1,
            "template": {
                "metadata": {"labels": {"fogfleet.io/instance": "x"}},
                "spec": {
                    "affinity": node_affinity(["cloud-1"]),
                    "containers": [{"name": "mapping", "image": "i"}],
                },
            },
        },
    }


def _fed(work: Obj, **values: int) -> Obj:
    name = work["spec"]["workload"]["manifests"][1]["metadata"]["name"]
    out = copy.deepcopy(work)
    out["status"] = {
        "resourceStatus": {
            "manifests": [
                {"resourceMeta": {"kind": "Namespace", "name": "warehouse"}},
                {
                    "resourceMeta": {"kind": "Deployment", "name": name},
                    "statusFeedback": {
                        "values": [
                            {"name": k, "fieldValue": {"type": "Integer", "integer": v}}
                            for k, v in values.items()
                        ]
                    },
                },
            ]
        }
    }
    return out


def test_the_work_carries_the_namespace_and_the_deployment_without_what_only_the_site_has() -> None:
    dep = _deployment()
    work = work_of(dep, "cloud", "site-a")
    assert work["metadata"]["namespace"] == "cloud"
    assert (
        work["metadata"]["labels"].items()
        >= work_selector("site-a", "warehouse", "warehouse").items()
    )
    ns, sent = work["spec"]["workload"]["manifests"]
    assert ns == {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": "warehouse"}}
    assert "ownerReferences" not in sent["metadata"]
    assert "affinity" not in sent["spec"]["template"]["spec"]
    assert (
        sent["spec"]["template"]["spec"]["containers"]
        == dep["spec"]["template"]["spec"]["containers"]
    )
    # the namespace is orphaned when the work goes; the Deployment is server-side applied
    orphans = work["spec"]["deleteOption"]["selectivelyOrphans"]["orphaningRules"]
    assert orphans == [{"group": "", "resource": "namespaces", "name": "warehouse"}]
    ns_cfg, dep_cfg = work["spec"]["manifestConfigs"]
    assert ns_cfg["updateStrategy"] == {"type": "CreateOnly"}
    assert dep_cfg["updateStrategy"]["type"] == "ServerSideApply"
    assert dep_cfg["updateStrategy"]["serverSideApply"]["fieldManager"].startswith("work-agent")
    paths = {p["name"] for p in dep_cfg["feedbackRules"][0]["jsonPaths"]}
    assert paths == set(FEEDBACK)
    assert dep["metadata"]["ownerReferences"]  # the site's object is left as it was


def test_two_sites_works_of_one_deployment_have_names_of_their_own() -> None:
    a = work_of(_deployment(), "cloud", "site-a")["metadata"]["name"]
    b = work_of(_deployment(), "cloud", "site-b")["metadata"]["name"]
    assert a != b and len(a) <= 63


def test_the_deployment_read_back_is_bound_to_its_node_with_the_fed_back_status() -> None:
    work = _fed(work_of(_deployment(), "cloud", "site-a"), generation=2, observedGeneration=2,
                replicas=1, updatedReplicas=1, availableReplicas=1)  # fmt: skip
    back = deployment_of(work)
    assert back is not None
    assert bound_nodes(back) == ["cloud-1"] and managed_cluster_of(back) == "cloud"
    assert back["metadata"]["annotations"][ANNOTATION_SPEC_HASH] == "h1"
    assert back["metadata"]["generation"] == 2
    assert back["status"] == {"observedGeneration": 2, "replicas": 1, "updatedReplicas": 1,
                              "availableReplicas": 1}  # fmt: skip
    assert current_placement([back]) == {("robot-1", "mapping", 0): "cloud-1"}


def test_before_any_feedback_the_deployment_read_back_has_nothing_available() -> None:
    back = deployment_of(work_of(_deployment(), "cloud", "site-a"))
    assert back is not None and back["status"] == {} and back["metadata"]["generation"] == 0


def test_a_work_that_is_not_ours_reads_back_as_nothing() -> None:
    assert (
        deployment_of({"metadata": {"name": "x"}, "spec": {"workload": {"manifests": []}}}) is None
    )
