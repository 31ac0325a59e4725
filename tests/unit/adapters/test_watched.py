"""WatchedKube: reads from its informers once synced (the API server before), its own
Deployment writes read back at once, and what the caches keep of each object."""

from __future__ import annotations

import pytest
from kubernetes import client

from fogfleet.adapters.kube import KubeClient
from fogfleet.adapters.watched import WatchedKube, trim_deployment, trim_node, trim_pod

MANAGED = {"app.kubernetes.io/managed-by": "fogfleet"}


def obj(name: str, ns: str = "a", rv: str = "1", **labels: str) -> dict:
    return {
        "metadata": {
            "name": name,
            "namespace": ns,
            "resourceVersion": rv,
            "labels": {**MANAGED, **labels},
            "managedFields": [{"manager": "x"}],
        },
        "spec": {"nodeName": "edge-1", "containers": [{"name": "c", "image": "i"}]},
        "status": {"phase": "Running", "conditions": [{"type": "Ready"}], "hostIP": "10.0.0.1"},
    }


@pytest.fixture
def kube(monkeypatch):
    calls: list[str] = []
    for name in ("list_pods", "list_deployments", "list_nodes", "list_modules"):
        monkeypatch.setattr(KubeClient, name, lambda self, *a, name=name: calls.append(name) or [])
    k = WatchedKube(client.ApiClient(client.Configuration()), namespaces=["a", "b"])
    k.calls = calls
    return k


def sync(kube: WatchedKube, informer, items: list[dict]) -> None:
    kube.list_versioned = lambda path, selector: (items, "100")  # type: ignore[method-assign]
    informer._relist()


def test_reads_go_to_the_api_server_until_the_cache_is_synced(kube):
    assert kube.list_pods("a", {"fogfleet.io/fleet": "f"}) == []
    assert kube.calls == ["list_pods"]
    sync(kube, kube.pods["a"], [obj("p1", **{"fogfleet.io/fleet": "f"}), obj("p2")])
    got = kube.list_pods("a", {"fogfleet.io/fleet": "f"})
    assert [p["metadata"]["name"] for p in got] == ["p1"] and kube.calls == ["list_pods"]
    # another served namespace is not synced yet; an unserved one is never cached
    kube.list_pods("b", {})
    kube.list_pods("elsewhere", {})
    assert kube.calls == ["list_pods", "list_pods", "list_pods"]


def test_modules_of_every_namespace_come_from_the_api_server_when_scoped(kube):
    for informer in kube.modules.values():
        sync(kube, informer, [])
    kube.list_modules("a")
    assert kube.calls == []
    kube.list_modules(None)
    assert kube.calls == ["list_modules"]


def test_a_cluster_wide_cache_serves_every_namespace(monkeypatch):
    k = WatchedKube(client.ApiClient(client.Configuration()))
    k.list_versioned = lambda path, selector: ([obj("p1", ns="x"), obj("p2", ns="y")], "5")  # type: ignore[method-assign]
    k.pods[None]._relist()
    assert [p["metadata"]["name"] for p in k.list_pods("y", {})] == ["p2"]


def test_an_applied_deployment_is_read_back_and_a_deleted_one_is_gone(kube, monkeypatch):
    sync(kube, kube.deployments["a"], [obj("d1")])
    monkeypatch.setattr(KubeClient, "apply_deployment", lambda self, body: {**body, "status": {}})
    monkeypatch.setattr(KubeClient, "delete_deployment", lambda self, ns, name: None)
    kube.apply_deployment(obj("d2", rv="7"))
    assert sorted(d["metadata"]["name"] for d in kube.list_deployments("a", {})) == ["d1", "d2"]
    kube.delete_deployment("a", "d1")
    assert [d["metadata"]["name"] for d in kube.list_deployments("a", {})] == ["d2"]
    assert kube.calls == []


def test_trims_keep_what_the_controllers_read():
    pod = trim_pod(obj("p"))
    assert pod["spec"] == {"nodeName": "edge-1"}
    assert pod["status"] == {"phase": "Running", "conditions": [{"type": "Ready"}]}
    assert "managedFields" not in pod["metadata"] and pod["metadata"]["labels"] == MANAGED
    affinity = {"nodeAffinity": {"required": 1}}
    dep = {
        "metadata": {"name": "d", "annotations": {"h": "1"}, "managedFields": []},
        "spec": {
            "replicas": 2,
            "template": {
                "metadata": {"labels": {"x": "y"}},
                "spec": {"affinity": affinity, "containers": [{"name": "big"}]},
            },
        },
        "status": {"availableReplicas": 2},
    }
    small = trim_deployment(dep)
    assert small["spec"] == {
        "replicas": 2,
        "template": {"metadata": {"labels": {"x": "y"}}, "spec": {"affinity": affinity}},
    }
    assert small["status"] == {"availableReplicas": 2} and "managedFields" not in small["metadata"]
    node = trim_node({"metadata": {"name": "n"}, "status": {"images": [1], "allocatable": {}}})
    assert node["status"] == {"allocatable": {}}
