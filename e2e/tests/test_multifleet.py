"""Fleets that share a cluster (issue 35): two fleets applied at the same moment on the same
edge nodes each plan into what the other left, and a third that cannot fit says why without
disturbing them. Real kube-apiserver and kube-scheduler, kwok nodes (the warehouse's)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    Operator,
    assert_pods_where_planned,
    condition_is,
    conditions,
    deployment_versions,
    example_docs,
    fleet,
    install_crds,
    of_kind,
    wait_ready,
)
from fogfleet.api.v1alpha1.base import parse_cpu

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's kwok warehouse nodes (robot-1..5, edge-1..6)"),
    pytest.mark.multifleet,
    pytest.mark.timeout(600),
]

ROBOTS = {"a": ["robot-1", "robot-2"], "b": ["robot-3", "robot-4"], "c": ["robot-1"]}
INSTANCES = 16  # 2 robots x 8 modules


def _fleet_docs(namespace: str, robots: list[str]) -> list[dict[str, Any]]:
    docs = example_docs("warehouse", namespace)
    body = of_kind(docs, "RobotFleet")[0]
    body["spec"]["robots"] = robots
    return [*of_kind(docs, "SoftwareModule"), body]


@pytest.fixture
def namespaces(kube: Kube, namespace: str) -> Iterator[dict[str, str]]:
    """Three namespaces: the test's own (fleet a) and two more (fleets b and c)."""
    names = {"a": namespace, "b": f"{namespace}-b", "c": f"{namespace}-c"}
    for key in ("b", "c"):
        kube.create_namespace(names[key])
    yield names
    for key in ("b", "c"):
        kube.kubectl("delete", "namespace", names[key], "--wait=false", check=False)


@pytest.fixture
def operator(kube: Kube, namespaces: dict[str, str], tmp_path: Path, diagnostics: list[Any]):
    install_crds(kube)
    op = Operator(kube.kubeconfig, list(namespaces.values()), tmp_path / "operator.log")
    diagnostics.append(lambda: ("operator log", op.logs(200)))
    op.start().wait_live()
    yield op
    for name in namespaces.values():
        kube.kubectl(
            "delete",
            "robotfleets",
            "--all",
            "-n",
            name,
            "--wait=true",
            "--timeout=60s",
            check=False,
            timeout=90,
        )
    op.stop()


def _requests_per_node(kube: Kube) -> dict[str, float]:
    """Node -> the CPU every pod bound there requests (every namespace)."""
    out: dict[str, float] = {}
    for pod in kube.kubectl_json("get", "pods", "-A")["items"]:
        node = pod["spec"].get("nodeName")
        if not node or pod["status"].get("phase") in ("Succeeded", "Failed"):
            continue
        for c in pod["spec"].get("containers") or []:
            cpu = ((c.get("resources") or {}).get("requests") or {}).get("cpu")
            if cpu:
                out[node] = out.get(node, 0.0) + parse_cpu(cpu)
    return out


def _shared_with(kube: Kube, namespace: str) -> set[str]:
    """Who the fleet's status says it shares nodes with."""
    shared = fleet(kube, namespace).get("status", {}).get("sharedNodes") or []
    return {holder for entry in shared for holder in entry["heldBy"]}


def test_two_fleets_share_nodes_and_a_third_that_cannot_fit_says_why(
    kube: Kube, namespaces: dict[str, str], operator: Operator
) -> None:
    ns = namespaces
    nodes = of_kind(example_docs("warehouse"), "ComputeNode")
    kube.apply(nodes + _fleet_docs(ns["a"], ROBOTS["a"]) + _fleet_docs(ns["b"], ROBOTS["b"]))
    for key in ("a", "b"):
        wait_ready(kube, ns[key], timeout=240)
        assert_pods_where_planned(kube, ns[key], instances=INSTANCES)
    allocatable = {
        n["metadata"]["name"]: parse_cpu(n["status"]["allocatable"]["cpu"])
        for n in kube.kubectl_json("get", "nodes")["items"]
    }
    for node, cpu in _requests_per_node(kube).items():
        assert cpu <= allocatable[node] + 1e-9, (node, cpu, allocatable[node])
    # each names the other on the edge nodes they share
    kube.wait_for(
        "both fleets naming each other in status.sharedNodes",
        lambda: (
            f"RobotFleet {ns['b']}/warehouse" in _shared_with(kube, ns["a"])
            and f"RobotFleet {ns['a']}/warehouse" in _shared_with(kube, ns["b"])
        ),
        timeout=120,
    )
    for key in ("a", "b"):
        wait_ready(kube, ns[key], timeout=120)
    before = {key: deployment_versions(kube, ns[key]) for key in ("a", "b")}

    # a third fleet on robot-1, whose on-board modules fleet a runs already: it cannot fit
    kube.apply(_fleet_docs(ns["c"], ROBOTS["c"]))
    kube.wait_for(
        "fleet c Scheduled=False",
        lambda: condition_is(kube, ns["c"], "Scheduled", "False"),
        timeout=120,
    )
    message = conditions(fleet(kube, ns["c"]))["Scheduled"]["message"]
    assert f"RobotFleet {ns['a']}/warehouse" in message and "robot-1" in message, message
    pods_c = kube.kubectl_json("get", "pods", "-n", ns["c"], "-l", "fogfleet.io/fleet")["items"]
    assert [p for p in pods_c if p["status"].get("phase") == "Pending"] == []
    for key in ("a", "b"):
        assert condition_is(kube, ns[key], "Ready", "True")
        assert deployment_versions(kube, ns[key]) == before[key]  # undisturbed
