"""The bed's cluster as users have theirs (issue 44): a Prometheus that finds pods through the
Kubernetes API and that pods reach at a cluster address by name, and cluster DNS.

Each test would fail on the bed before issue 44: Prometheus read a target file the harness
wrote, pods could not reach it (it listened on the host's loopback), and every pod on a real
node got a ``MissingClusterDNS`` Warning and an empty resolv.conf.
"""

from __future__ import annotations

import json
import time
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's real nodes, its Prometheus and its cluster DNS"),
    pytest.mark.real,
    pytest.mark.inclusterloop,
    pytest.mark.timeout(300),
]

BUSYBOX = "localhost/fogfleet/busybox:bed"
PYTHON = "ghcr.io/fogfleet/ros2-module:0.1.0"  # glibc's resolver, as the operator's image has
METRICS = "fogfleet_bed_probe_up 1\n"

# What the operator's own image does to reach Prometheus: resolve the Service by its short name
# through the pod's search list, then an HTTP GET; plus names that must not resolve.
CLIENT = """
import json, socket, urllib.request
out = {}
for name in ("prometheus.monitoring.svc", "prometheus.monitoring.svc.cluster.local",
             "kubernetes.default.svc", "example.com", "localhost.localdomain.fogfleet.invalid"):
    try:
        out[name] = sorted({a[4][0] for a in socket.getaddrinfo(name, None, socket.AF_INET)})
    except OSError as exc:
        out[name] = "error: %s" % exc
with urllib.request.urlopen("PROMETHEUS_URL/api/v1/status/buildinfo", timeout=10) as resp:
    out["buildinfo"] = json.load(resp)["data"]
out["resolv.conf"] = open("/etc/resolv.conf").read()
print(json.dumps(out))
"""


def _pod(name: str, node: str, image: str, command: list[str], **meta: Any) -> dict[str, Any]:
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": name, "labels": {"app": name}, **meta},
        "spec": {
            "nodeSelector": {"kubernetes.io/hostname": node},
            "automountServiceAccountToken": False,
            "terminationGracePeriodSeconds": 1,
            "restartPolicy": "Never",
            "containers": [
                {
                    "name": "main",
                    "image": image,
                    "imagePullPolicy": "Never",
                    "command": command,
                    "securityContext": {"allowPrivilegeEscalation": False},
                    "resources": {"limits": {"cpu": "200m", "memory": "128Mi"}},
                }
            ],
        },
    }


def _phase(kube: Kube, namespace: str, name: str) -> str:
    pod = kube.kubectl_json("get", "pod", name, "-n", namespace)
    return str(pod["status"].get("phase", ""))


def _run_to_end(kube: Kube, namespace: str, pod: dict[str, Any], timeout: float) -> str:
    """Apply a pod that runs to its end; its phase (Succeeded or Failed) once it ended."""
    name = pod["metadata"]["name"]
    kube.apply(pod, namespace)
    kube.wait_for(
        f"the {name} pod to finish",
        lambda: _phase(kube, namespace, name) in ("Succeeded", "Failed"),
        timeout,
    )
    return _phase(kube, namespace, name)


def _active_targets(cluster: Cluster) -> list[dict[str, Any]]:
    from e2e.bed.base import http_get

    body = json.loads(http_get(f"{cluster.prometheus_url}/api/v1/targets?state=active"))
    targets: list[dict[str, Any]] = body["data"]["activeTargets"]
    return targets


@pytest.fixture
def real_node(cluster: Cluster) -> str:
    assert cluster.real_nodes, "the bed runs no real nodes"
    return cluster.real_nodes[-1]


def test_prometheus_finds_an_annotated_pod_through_the_api_and_no_fake_pod(
    kube: Kube, cluster: Cluster, namespace: str, real_node: str
) -> None:
    """An annotated pod on a real node is scraped with the kubernetes-pods labels, found from
    the API (no file of the harness names it); an annotated kwok pod is never a target."""
    annotations = {
        "prometheus.io/scrape": "true",
        "prometheus.io/port": "8080",
        "prometheus.io/path": "/metrics",
    }
    # busybox's httpd serves the file as application/octet-stream: Prometheus 3 scrapes it only
    # because the bed's jobs name a fallback protocol, as a user's must for such exporters
    serve = (
        f"busybox mkdir -p /tmp/www && printf '{METRICS}' > /tmp/www/metrics && "
        "exec busybox httpd -f -p 8080 -h /tmp/www"
    )
    kube.apply(
        _pod("exporter", real_node, BUSYBOX, ["sh", "-c", serve], annotations=annotations),
        namespace,
    )
    fake = _pod("fake-exporter", "solo-edge", BUSYBOX, ["sh"], annotations=annotations)
    fake["spec"]["tolerations"] = [{"operator": "Exists"}]
    kube.apply(fake, namespace)
    kube.wait_for(
        "the exporter pod Running", lambda: _phase(kube, namespace, "exporter") == "Running", 90
    )
    kube.wait_for(
        "the kwok pod Running", lambda: _phase(kube, namespace, "fake-exporter") == "Running", 60
    )

    def scraped() -> list[dict[str, Any]]:
        return cluster.prometheus_query(f'fogfleet_bed_probe_up{{namespace="{namespace}"}}')

    kube.wait_for("Prometheus to scrape the exporter pod", lambda: bool(scraped()), 60)
    (series,) = scraped()
    labels = series["metric"]
    assert labels["job"] == "kubernetes-pods"
    assert (labels["namespace"], labels["pod"], labels["node"]) == (
        namespace,
        "exporter",
        real_node,
    )
    pod_ip = kube.kubectl_json("get", "pod", "exporter", "-n", namespace)["status"]["podIP"]
    assert labels["instance"] == f"{pod_ip}:8080"
    # found through the API: no target file of the harness's names the pod
    for path in cluster.prometheus_targets_dir.glob("*.json"):
        assert pod_ip not in path.read_text(), path
    pools = {
        t["scrapePool"]
        for t in _active_targets(cluster)
        if t["labels"].get("namespace") == namespace
    }
    assert pools == {"kubernetes-pods"}
    names = {t["labels"].get("pod") for t in _active_targets(cluster)}
    assert "fake-exporter" not in names  # kwok's pod IPs lead nowhere: never scraped
    # and the scrape is up for the whole window the operator's queries read
    time.sleep(4)
    up = cluster.prometheus_query(f'up{{namespace="{namespace}",pod="exporter"}}')
    assert [s["value"][1] for s in up] == ["1"]


def test_a_pod_on_a_real_node_reaches_prometheus_by_its_service_name(
    kube: Kube, cluster: Cluster, namespace: str, real_node: str
) -> None:
    """From a pod: the cluster DNS resolves the Service names (short, with the search list,
    and full), refuses names outside cluster.local, and Prometheus answers at the in-cluster
    URL the Cluster object gives."""
    assert cluster.in_cluster_prometheus_url == "http://prometheus.monitoring.svc:9090"
    script = CLIENT.replace("PROMETHEUS_URL", cluster.in_cluster_prometheus_url)
    phase = _run_to_end(
        kube, namespace, _pod("client", real_node, PYTHON, ["python3", "-c", script]), 120
    )
    logs = kube.kubectl("logs", "client", "-n", namespace).stdout
    assert phase == "Succeeded", logs
    out = json.loads(logs.strip().splitlines()[-1])
    service_ip = kube.kubectl_json("get", "service", "prometheus", "-n", "monitoring")["spec"][
        "clusterIP"
    ]
    assert out["prometheus.monitoring.svc"] == [service_ip]
    assert out["prometheus.monitoring.svc.cluster.local"] == [service_ip]
    assert out["kubernetes.default.svc"] == ["198.19.0.1"]
    # nothing outside the bed is asked: names outside cluster.local do not resolve
    assert str(out["example.com"]).startswith("error")
    assert str(out["localhost.localdomain.fogfleet.invalid"]).startswith("error")
    assert out["buildinfo"]["version"] == cluster.versions.get("PROMETHEUS_VERSION", "3.16.0")
    assert f"nameserver {cluster.dns_service_ip}" in out["resolv.conf"]
    assert (
        f"search {namespace}.svc.cluster.local svc.cluster.local cluster.local"
        in out["resolv.conf"]
    )


def test_names_outside_cluster_local_are_refused_not_forwarded(
    kube: Kube, cluster: Cluster, namespace: str, real_node: str
) -> None:
    """busybox's own resolver asks the cluster DNS directly: a Service name answers, any other
    name is REFUSED by CoreDNS (it has no forward plugin)."""
    script = (
        "busybox nslookup prometheus.monitoring.svc.cluster.local; echo rc=$?; "
        "busybox nslookup debian.org.; echo rc=$?"
    )
    _run_to_end(kube, namespace, _pod("lookup", real_node, BUSYBOX, ["sh", "-c", script]), 90)
    logs = kube.kubectl("logs", "lookup", "-n", namespace).stdout
    first, second = logs.split("rc=", 1)[0], logs.split("rc=", 1)[1]
    assert "Address" in first and "rc=0" in logs, logs
    assert "REFUSED" in second or "can't find" in second, logs


def test_no_pod_of_the_bed_gets_a_missing_cluster_dns_event(
    kube: Kube, cluster: Cluster, namespace: str, real_node: str
) -> None:
    """Every kubelet has a cluster DNS: not a pod of the bed, in any namespace, has the
    MissingClusterDNS Warning (kwok's pods never had one: kwok sends no such events)."""
    idle = _pod("idle", real_node, BUSYBOX, ["busybox", "sleep", "5"])
    assert _run_to_end(kube, namespace, idle, 90) == "Succeeded"
    events = kube.kubectl_json(
        "get", "events", "-A", "--field-selector", "reason=MissingClusterDNS"
    )
    assert events["items"] == [], [
        (e["involvedObject"].get("namespace"), e["involvedObject"].get("name"), e["message"])
        for e in events["items"]
    ]
