"""The operator's watch-fed caches against the real API server: a list then a watch keep the
cache equal to the cluster, our own writes are read back at once, and changes made by others
(kube-scheduler binding, kwok running the pod, kubectl deleting) arrive as events."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.tests.test_smoke import _deployment, _ready_nodes

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("a kwok robot node (fogfleet.io/tier=robot without e2e-real)"),
    pytest.mark.timeout(180),
]

MANAGED = {"app.kubernetes.io/managed-by": "fogfleet"}


def _watched(kube: Kube, namespace: str) -> Any:
    from fogfleet.adapters.kube import load_config
    from fogfleet.adapters.watched import WatchedKube

    return WatchedKube(load_config(str(kube.kubeconfig)), namespaces=[namespace])


def _until(what: str, check: Any, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"timed out after {timeout:.0f}s waiting for {what}"
        time.sleep(0.05)


def test_the_caches_follow_the_cluster_and_read_our_writes_back(kube: Kube, namespace: str):
    robots = _ready_nodes(kube, "fogfleet.io/tier=robot,!fogfleet.io/e2e-real")
    assert robots, "need a Ready kwok robot node"
    hostname = kube.kubectl_json("get", "node", robots[0])["metadata"]["labels"][
        "kubernetes.io/hostname"
    ]
    # one Deployment exists before the cache starts (the list), one is written through it
    before = _deployment("listed", 1, hostname)
    before["metadata"]["labels"] = dict(MANAGED)
    before["spec"]["template"]["metadata"]["labels"] |= MANAGED
    kube.apply(before, namespace=namespace)

    watched = _watched(kube, namespace)
    events: list[tuple[str, str, bool]] = []
    lock = threading.Lock()

    def on_pod(kind: str, pod: dict, old: dict | None) -> None:
        with lock:
            events.append((kind, pod["metadata"]["name"], pod["status"].get("phase") == "Running"))

    watched.start(on_pod=on_pod)
    try:
        _until(
            "the caches' first lists", lambda: all(i.synced.is_set() for i in watched.informers())
        )
        assert [d["metadata"]["name"] for d in watched.list_deployments(namespace, {})] == [
            "listed"
        ]
        nodes = {n["metadata"]["name"] for n in watched.list_nodes()}
        assert robots[0] in nodes and "images" not in watched.list_nodes()[0].get("status", {})

        written = _deployment("written", 1, hostname)
        written["metadata"] |= {"namespace": namespace, "labels": dict(MANAGED)}
        written["spec"]["template"]["metadata"]["labels"] |= MANAGED
        stored = watched.apply_deployment(written)
        # read back at once, before its watch event could be relied on
        names = {d["metadata"]["name"] for d in watched.list_deployments(namespace, {})}
        assert names == {"listed", "written"}
        assert stored["metadata"]["resourceVersion"]

        # kube-scheduler binds and kwok runs the pods: the cache hears it
        def running() -> set[str]:
            return {
                p["metadata"]["labels"]["app"]
                for p in watched.list_pods(namespace, {})
                if p["status"].get("phase") == "Running" and p["spec"]["nodeName"] == robots[0]
            }

        _until("both pods Running in the cache", lambda: running() == {"listed", "written"})
        with lock:
            assert any(kind == "MODIFIED" and ok for kind, _, ok in events)
        pod = watched.list_pods(namespace, {})[0]
        assert set(pod["spec"]) == {"nodeName"} and "managedFields" not in pod["metadata"]
        # the Deployments' status follows (what the fleet's Ready condition reads)
        _until(
            "the Deployments available in the cache",
            lambda: all(
                (d.get("status") or {}).get("availableReplicas") == 1
                for d in watched.list_deployments(namespace, {})
            ),
        )

        # someone else deletes: the watch removes it
        kube.kubectl("delete", "deployment", "listed", "-n", namespace, "--wait=false")
        _until(
            "the deleted Deployment gone from the cache",
            lambda: (
                {d["metadata"]["name"] for d in watched.list_deployments(namespace, {})}
                == {"written"}
            ),
        )
        assert all(i.lists == 1 for i in watched.informers()), "no re-list was needed"
    finally:
        watched.stop()
