"""The test bed is a real Kubernetes: scheduler, admission/validation, RBAC, Prometheus.

Each test would fail on a fake API (a mock, a bare etcd+apiserver, a Prometheus that scrapes
nothing): pods must be bound by kube-scheduler, invalid objects rejected by the apiserver's
OpenAPI validation, a ServiceAccount token limited by RBAC, and PromQL must see live targets.
"""

from __future__ import annotations

import http.server
import json
import secrets
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.fakenodes import SIMULATED_TAINT, only_simulated_taint
from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from fogfleet.render.ros import PLANNED_TOLERATION

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("kwok node controls and the bed's Prometheus"),
    pytest.mark.timeout(300),
]

PAUSE_IMAGE = "registry.k8s.io/pause:3.10"  # never pulled on kwok; tiny and real on k3d


def _ready_nodes(kube: Kube, selector: str) -> list[str]:
    items = kube.kubectl_json("get", "nodes", "-l", selector)["items"]
    names = []
    for node in items:
        conds = {c["type"]: c["status"] for c in node["status"].get("conditions", [])}
        if conds.get("Ready") == "True" and only_simulated_taint(node):
            names.append(node["metadata"]["name"])
    return sorted(names)


def _deployment(name: str, replicas: int, hostname: str) -> dict[str, Any]:
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {"name": name},
        "spec": {
            "replicas": replicas,
            "selector": {"matchLabels": {"app": name}},
            "template": {
                "metadata": {"labels": {"app": name}},
                "spec": {
                    "affinity": {
                        "nodeAffinity": {
                            "requiredDuringSchedulingIgnoredDuringExecution": {
                                "nodeSelectorTerms": [
                                    {
                                        "matchExpressions": [
                                            {
                                                "key": "kubernetes.io/hostname",
                                                "operator": "In",
                                                "values": [hostname],
                                            }
                                        ]
                                    }
                                ]
                            }
                        }
                    },
                    "tolerations": [PLANNED_TOLERATION],  # fake nodes take planned pods only
                    "containers": [
                        {
                            "name": "main",
                            "image": PAUSE_IMAGE,
                            "resources": {"requests": {"cpu": "100m", "memory": "64Mi"}},
                        }
                    ],
                },
            },
        },
    }


def test_pods_of_a_pinned_deployment_run_on_exactly_that_node(kube: Kube, namespace: str) -> None:
    robots = _ready_nodes(kube, "fogfleet.io/tier=robot,!fogfleet.io/e2e-real")
    assert len(robots) >= 2, f"need two Ready robot nodes, found {robots}"
    target = robots[-1]  # not the first one, so a scheduler ignoring affinity is caught
    hostname = kube.kubectl_json("get", "node", target)["metadata"]["labels"][
        "kubernetes.io/hostname"
    ]
    kube.apply(_deployment("pinned", 3, hostname), namespace=namespace)

    kube.kubectl(
        "rollout", "status", "deployment/pinned", "-n", namespace, "--timeout=120s", timeout=150
    )

    pods = kube.kubectl_json("get", "pods", "-n", namespace, "-l", "app=pinned")["items"]
    assert len(pods) == 3
    assert {p["spec"].get("nodeName") for p in pods} == {target}
    assert {p["status"]["phase"] for p in pods} == {"Running"}
    # bound by the real kube-scheduler, not by someone setting spec.nodeName
    events = kube.kubectl_json(
        "get", "events", "-n", namespace, "--field-selector=reason=Scheduled"
    )["items"]
    scheduled = {e["involvedObject"]["name"]: e for e in events}
    for pod in pods:
        event = scheduled.get(pod["metadata"]["name"])
        assert event is not None, f"no Scheduled event for {pod['metadata']['name']}"
        component = event.get("reportingComponent") or event["source"].get("component")
        assert component == "default-scheduler"
        assert f"to {target}" in event["message"]


def test_pods_that_fit_no_node_stay_pending(kube: Kube, namespace: str) -> None:
    kube.apply(_deployment("nowhere", 1, "no-such-node"), namespace=namespace)

    def failed_scheduling() -> bool:
        events = kube.kubectl_json(
            "get", "events", "-n", namespace, "--field-selector=reason=FailedScheduling"
        )["items"]
        return any("didn't match" in e["message"] or "affinity" in e["message"] for e in events)

    kube.wait_for("a FailedScheduling event", failed_scheduling, timeout=60)
    pods = kube.kubectl_json("get", "pods", "-n", namespace, "-l", "app=nowhere")["items"]
    assert [p["status"]["phase"] for p in pods] == ["Pending"]
    assert not pods[0]["spec"].get("nodeName")


@pytest.fixture
def widget_crd(kube: Kube) -> Iterator[dict[str, str]]:
    suffix = secrets.token_hex(3)
    plural, group = f"smokewidgets{suffix}", "e2e.fogfleet.io"
    kind = f"SmokeWidget{suffix.upper()}"
    crd = {
        "apiVersion": "apiextensions.k8s.io/v1",
        "kind": "CustomResourceDefinition",
        "metadata": {"name": f"{plural}.{group}"},
        "spec": {
            "group": group,
            "scope": "Namespaced",
            "names": {"plural": plural, "singular": f"smokewidget{suffix}", "kind": kind},
            "versions": [
                {
                    "name": "v1",
                    "served": True,
                    "storage": True,
                    "schema": {
                        "openAPIV3Schema": {
                            "type": "object",
                            "properties": {
                                "spec": {
                                    "type": "object",
                                    "required": ["tier"],
                                    "properties": {
                                        "tier": {
                                            "type": "string",
                                            "enum": ["robot", "edge", "cloud"],
                                        },
                                        "replicas": {
                                            "type": "integer",
                                            "minimum": 0,
                                            "maximum": 10,
                                        },
                                    },
                                }
                            },
                        }
                    },
                }
            ],
        },
    }
    kube.apply(crd)
    kube.kubectl("wait", "--for=condition=Established", f"crd/{plural}.{group}", "--timeout=60s")
    yield {"group": group, "version": "v1", "plural": plural, "kind": kind}
    kube.kubectl("delete", "crd", f"{plural}.{group}", "--wait=false", check=False)


def test_crd_schema_rejects_an_invalid_object_with_422(
    kube: Kube, namespace: str, widget_crd: dict[str, str]
) -> None:
    from kubernetes import client
    from kubernetes.client.exceptions import ApiException

    api = client.CustomObjectsApi(kube.api_client())
    g, v, p, kind = (
        widget_crd["group"],
        widget_crd["version"],
        widget_crd["plural"],
        widget_crd["kind"],
    )

    def body(name: str, spec: dict[str, Any]) -> dict[str, Any]:
        return {"apiVersion": f"{g}/{v}", "kind": kind, "metadata": {"name": name}, "spec": spec}

    # the CRD is served and accepts a valid object (so the 422 below is about the schema)
    # (a CRD just Established can answer 404 for a moment while discovery catches up)
    deadline = time.monotonic() + 30
    while True:
        try:
            created: Any = api.create_namespaced_custom_object(
                g, v, namespace, p, body("good", {"tier": "edge", "replicas": 2})
            )
            break
        except ApiException as exc:
            if exc.status != 404 or time.monotonic() > deadline:
                raise
            time.sleep(0.5)
    assert created["spec"] == {"tier": "edge", "replicas": 2}

    with pytest.raises(ApiException) as info:
        api.create_namespaced_custom_object(
            g, v, namespace, p, body("bad", {"tier": "moon", "replicas": 11})
        )
    assert info.value.status == 422
    status = json.loads(str(info.value.body))
    assert status["reason"] == "Invalid"
    fields = {cause.get("field") for cause in status["details"]["causes"]}
    assert {"spec.tier", "spec.replicas"} <= fields, status["message"]

    with pytest.raises(ApiException) as missing:
        api.create_namespaced_custom_object(g, v, namespace, p, body("empty", {"replicas": 1}))
    assert missing.value.status == 422
    assert "spec.tier" in json.loads(str(missing.value.body))["message"]


def test_serviceaccount_token_is_limited_to_its_role(
    kube: Kube, namespace: str, tmp_path: Path
) -> None:
    kube.apply(
        [
            {"apiVersion": "v1", "kind": "ServiceAccount", "metadata": {"name": "reader"}},
            {
                "apiVersion": "rbac.authorization.k8s.io/v1",
                "kind": "Role",
                "metadata": {"name": "pod-reader"},
                "rules": [
                    {"apiGroups": [""], "resources": ["pods"], "verbs": ["get", "list"]},
                    {"apiGroups": [""], "resources": ["configmaps"], "verbs": ["get"]},
                ],
            },
            {
                "apiVersion": "rbac.authorization.k8s.io/v1",
                "kind": "RoleBinding",
                "metadata": {"name": "reader-reads-pods"},
                "roleRef": {
                    "apiGroup": "rbac.authorization.k8s.io",
                    "kind": "Role",
                    "name": "pod-reader",
                },
                "subjects": [{"kind": "ServiceAccount", "name": "reader", "namespace": namespace}],
            },
            {
                "apiVersion": "v1",
                "kind": "ConfigMap",
                "metadata": {"name": "visible"},
                "data": {"k": "v"},
            },
        ],
        namespace=namespace,
    )
    token = kube.kubectl(
        "create", "token", "reader", "-n", namespace, "--duration=10m"
    ).stdout.strip()
    assert token.count(".") == 2  # a JWT
    as_reader = kube.token_kubeconfig(token, tmp_path / "reader.kubeconfig")
    user = f"system:serviceaccount:{namespace}:reader"

    def reader(*args: str) -> Any:
        return kube.kubectl(*args, kubeconfig=as_reader, check=False)

    # allowed (retry briefly: the RBAC authorizer's cache may lag the RoleBinding)
    kube.wait_for(
        "the RoleBinding to take effect",
        lambda: reader("get", "pods", "-n", namespace).returncode == 0,
        timeout=30,
    )
    got = reader("get", "configmap", "visible", "-n", namespace, "-o", "jsonpath={.data.k}")
    assert got.returncode == 0, got.stderr
    assert got.stdout == "v"

    # denied: verbs, resources and namespaces the Role does not grant
    for args, verb, resource in (
        (
            ("create", "configmap", "nope", "-n", namespace, "--from-literal=a=b"),
            "create",
            "configmaps",
        ),
        (("get", "secrets", "-n", namespace), "list", "secrets"),
        (("get", "pods", "-n", "default"), "list", "pods"),
        (("delete", "configmap", "visible", "-n", namespace), "delete", "configmaps"),
    ):
        denied = reader(*args)
        assert denied.returncode != 0, f"{args} was allowed"
        assert "forbidden" in denied.stderr.lower(), denied.stderr
        assert f'User "{user}" cannot {verb} resource "{resource}"' in denied.stderr
    assert kube.kubectl("get", "configmap", "visible", "-n", namespace).returncode == 0


def _wait_query(cluster: Cluster, promql: str, want: str, timeout: float = 60) -> list[Any]:
    deadline = time.monotonic() + timeout
    result: list[Any] = []
    while time.monotonic() < deadline:
        result = cluster.prometheus_query(promql)
        if result and all(r["value"][1] == want for r in result):
            return result
        time.sleep(1)
    raise AssertionError(f"{promql} did not become {want} within {timeout}s; last: {result}")


def test_prometheus_scrapes_the_control_plane(cluster: Cluster) -> None:
    port = cluster.ports["kube-apiserver"]
    up = _wait_query(cluster, 'up{job="kube-apiserver"}', "1")
    assert [r["metric"]["instance"] for r in up] == [f"127.0.0.1:{port}"]
    for job in ("etcd", "kube-controller-manager", "kube-scheduler", "kwok"):
        _wait_query(cluster, f'up{{job="{job}"}}', "1")
    # real apiserver metrics, not just a reachable port
    requests = cluster.prometheus_query('sum(apiserver_request_total{job="kube-apiserver"})')
    assert requests and float(requests[0]["value"][1]) > 0


class _Exporter(http.server.BaseHTTPRequestHandler):
    value = 0
    scrapes = 0

    def do_GET(self) -> None:
        type(self).scrapes += 1
        body = (
            f"# TYPE fogfleet_e2e_smoke_value gauge\nfogfleet_e2e_smoke_value {type(self).value}\n"
        ).encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/plain; version=0.0.4")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: Any) -> None:
        pass


def test_prometheus_scrapes_a_target_added_through_file_sd(cluster: Cluster) -> None:
    class handler(_Exporter):  # a fresh class: its own value and scrape counter
        value = secrets.randbelow(10**6) + 1
        scrapes = 0

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    job = f"smoke-{secrets.token_hex(3)}"
    try:
        cluster.add_prometheus_target(job, f"127.0.0.1:{server.server_address[1]}")
        result = _wait_query(
            cluster, f'fogfleet_e2e_smoke_value{{job="{job}"}}', str(handler.value)
        )
        assert len(result) == 1
        assert handler.scrapes >= 1
    finally:
        cluster.remove_prometheus_target(job)
        server.shutdown()
        server.server_close()


def _ready_status(kube: Kube, node: str) -> tuple[str, set[str]]:
    obj = kube.kubectl_json("get", "node", node)
    conds = {c["type"]: c["status"] for c in obj["status"].get("conditions", [])}
    taints = {t["key"] for t in obj["spec"].get("taints") or [] if t != SIMULATED_TAINT}
    return conds.get("Ready", "?"), taints


def test_a_node_can_be_made_not_ready_and_recover(kube: Kube, cluster: Cluster) -> None:
    edges = _ready_nodes(kube, "fogfleet.io/tier=edge,!fogfleet.io/e2e-real")
    assert len(edges) >= 2, f"need two Ready edge nodes, found {edges}"
    reported, lost = edges[-1], edges[-2]
    try:
        cluster.set_node_not_ready(reported)  # kwok reports Ready=False
        cluster.stop_node_heartbeat(lost)  # kwok stops renewing the Lease
        kube.wait_for(
            f"{reported} NotReady and tainted",
            lambda: _ready_status(kube, reported) == ("False", {"node.kubernetes.io/not-ready"}),
            timeout=30,
        )
        kube.wait_for(
            f"{lost} Unknown and tainted unreachable",
            lambda: _ready_status(kube, lost) == ("Unknown", {"node.kubernetes.io/unreachable"}),
            timeout=60,
        )
    finally:
        cluster.set_node_not_ready(reported, False)
        cluster.resume_node_heartbeat(lost)
    for node in (reported, lost):

        def recovered(n: str = node) -> bool:
            return _ready_status(kube, n) == ("True", set())

        kube.wait_for(f"{node} Ready and untainted again", recovered, timeout=60)
