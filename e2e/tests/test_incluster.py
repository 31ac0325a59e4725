"""The operator as users install it: `helm install` of the chart, from its image, on a real node.

The image is the one `make images` builds from the repository's Dockerfile, imported into the
real nodes' containerd; the operator reaches the API server through the `kubernetes` Service
(kube-proxy on the node), with its ServiceAccount token and the chart's RBAC. Two replicas
elect a leader on a Lease. The tests run in file order: install, upgrade, failover, uninstall.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    CHART,
    N_INSTANCES,
    apply_warehouse,
    assert_pods_where_planned,
    deployment_versions,
    deployments,
    fleet,
    helm,
    wait_ready,
)
from e2e.tests.incluster import (
    RELEASE,
    SYSTEM,
    installed,
    kill_leader,
    leader,
    operator_pods,
    running_pod_names,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's real node names and its helm; test_portable.py installs portably"),
    pytest.mark.real,
    pytest.mark.incluster,
    pytest.mark.timeout(600),
]


@pytest.fixture(scope="module")
def watched(kube: Kube, cluster: Cluster) -> Iterator[str]:
    """The namespace the installed operator watches (the release itself is in fogfleet-system)."""
    with installed(kube) as ns:
        yield ns


def test_helm_install_runs_the_operator_image_on_a_real_node_that_is_not_a_robot(
    kube: Kube, cluster: Cluster, watched: str
) -> None:
    pods = operator_pods(kube)
    assert len(pods) == 2, [p["metadata"]["name"] for p in pods]
    for pod in pods:
        node = kube.kubectl_json("get", "node", pod["spec"]["nodeName"])
        labels = node["metadata"]["labels"]
        assert pod["spec"]["nodeName"] in cluster.real_nodes
        assert labels.get("fogfleet.io/tier") != "robot", pod["spec"]["nodeName"]
        (status,) = pod["status"]["containerStatuses"]
        assert status["image"].endswith("ghcr.io/fogfleet/fogfleet:0.1.0"), status["image"]
        assert status["ready"] is True
    kube.wait_for("a leader", lambda: leader(kube) in {p["metadata"]["name"] for p in pods}, 60)

    apply_warehouse(kube, watched)
    wait_ready(kube, watched, timeout=300)
    assert_pods_where_planned(kube, watched)


def test_helm_upgrade_rolls_the_operator_without_touching_running_modules(
    kube: Kube, watched: str
) -> None:
    before_pods = {p["metadata"]["name"] for p in operator_pods(kube)}
    before = deployment_versions(kube, watched)
    assert len(before) == N_INSTANCES
    helm(
        "upgrade", RELEASE, str(CHART), "-n", SYSTEM, "--reuse-values",
        "--set", "logLevel=debug", "--wait", "--timeout", "240s",
    )  # fmt: skip
    kube.wait_for(
        "only the rolled operator pods",
        lambda: (
            len(running_pod_names(kube) - before_pods) == 2
            and len(operator_pods(kube, terminating=True)) == 2
        ),
        180,
    )
    # the old leader released the Lease on its way out: a new pod leads
    # generous (the new pods run already; a released Lease is taken at once): guards a hang
    kube.wait_for("a new leader", lambda: leader(kube) in running_pod_names(kube), 60)
    # an observation window, not a wait: a resumed operator re-checks every fleet, and must
    # not write a Deployment when it does (a loaded machine may make the window see less of
    # it; it cannot make the test fail)
    time.sleep(10)
    assert deployment_versions(kube, watched) == before
    wait_ready(kube, watched)


def test_killing_the_leader_mid_reconcile_hands_over_within_30_s_without_duplicates(
    kube: Kube, watched: str
) -> None:
    # a change that re-plans the whole fleet, then the leader dies at once
    patch = {"spec": {"scheduler": {"seed": 7}}}
    kube.kubectl("patch", "robotfleet", "warehouse", "-n", watched, "--type=merge",
                 "-p", json.dumps(patch))  # fmt: skip
    generation = fleet(kube, watched)["metadata"]["generation"]
    new, took = kill_leader(kube, 30)
    print(f"failover: new leader {new} after {took:.1f}s")
    assert took <= 30  # the chart's 15 s Lease, then the standby's retry
    kube.wait_for(
        "the new leader's reconcile",
        lambda: (fleet(kube, watched).get("status") or {}).get("observedGeneration") == generation,
        120,
    )
    wait_ready(kube, watched)
    deps = deployments(kube, watched)
    assert len(deps) == N_INSTANCES, sorted(d["metadata"]["name"] for d in deps)
    owner = fleet(kube, watched)["metadata"]["uid"]
    assert all(d["metadata"]["ownerReferences"][0]["uid"] == owner for d in deps)
    assert len({d["metadata"]["annotations"]["fogfleet.io/plan-id"] for d in deps}) == 1
    assert_pods_where_planned(kube, watched)


def test_helm_uninstall_leaves_only_the_crds_and_nothing_is_stuck(kube: Kube, watched: str) -> None:
    helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
    for kind in ("clusterrole", "clusterrolebinding"):
        proc = kube.kubectl("get", kind, "fogfleet-operator", check=False)
        assert proc.returncode != 0, f"{kind} fogfleet-operator survived helm uninstall"
    for crd in ("robotfleets", "softwaremodules", "computenodes"):
        kube.kubectl("get", "crd", f"{crd}.fogfleet.io")
    kube.wait_for("the operator pods gone", lambda: operator_pods(kube) == [], 60)
    # no operator any more: deleting the fleet's namespace must not hang on a finalizer
    t0 = time.monotonic()
    kube.kubectl("delete", "namespace", watched, "--wait=false")
    kube.wait_for(
        f"namespace {watched} gone",
        lambda: kube.kubectl("get", "namespace", watched, check=False).returncode != 0,
        60,
    )
    print(f"namespace deleted in {time.monotonic() - t0:.1f}s without the operator")
