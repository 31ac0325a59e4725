"""Real nodes: real containers run, CPU limits and node shares hold, links carry their delay.

Each test would fail on kwok: a fake pod has no process, no cgroup, no log and no network.
They use the bed's powers (a node's cgroups, its emulated link), so they need the local bed.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest

from e2e.bed import cgroups, realnodes
from e2e.bed.harness import NODES_FILE, Cluster
from e2e.bed.kube import Kube

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the real nodes' cgroups and emulated links"),
    pytest.mark.real,
    pytest.mark.timeout(300),
]

BUSYBOX = "localhost/fogfleet/busybox:bed"


@pytest.fixture(scope="module")
def bed_nodes(cluster: Cluster) -> dict[str, realnodes.RealNode]:
    _, declared = realnodes.split_manifest(NODES_FILE.read_text())
    assert cluster.real_nodes, "the bed runs no real nodes (nodes.yaml declares them)"
    return {n.name: n for n in declared if n.name in cluster.real_nodes}


def _pod(name: str, node: str, command: str, cpu: str | None = None) -> dict[str, Any]:
    container: dict[str, Any] = {
        "name": "main",
        "image": BUSYBOX,
        "imagePullPolicy": "Never",
        "command": ["sh", "-c", command],
        "securityContext": {"allowPrivilegeEscalation": False},
    }
    if cpu:
        container["resources"] = {"limits": {"cpu": cpu, "memory": "32Mi"}}
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": name, "labels": {"app": name}},
        "spec": {
            # kube-scheduler binds it: the real node must fit it like any node
            "nodeSelector": {"kubernetes.io/hostname": node},
            "automountServiceAccountToken": False,
            "terminationGracePeriodSeconds": 1,
            "containers": [container],
        },
    }


def _running(kube: Kube, namespace: str, name: str, timeout: float = 90) -> dict[str, Any]:
    def get() -> dict[str, Any]:
        pod: dict[str, Any] = kube.kubectl_json("get", "pod", name, "-n", namespace)
        return pod

    kube.wait_for(f"pod {name} Running", lambda: get()["status"].get("phase") == "Running", timeout)
    return get()


def _pod_cgroup(node: realnodes.RealNode, uid: str) -> str:
    base = cgroups.CGROUP_ROOT / "cpuacct" / node.cgroup.lstrip("/") / "pods"
    found = [p for p in base.rglob(f"pod{uid}") if p.is_dir()]
    assert found, f"no cgroup for pod {uid} below {base}"
    return "/" + str(found[0].relative_to(cgroups.CGROUP_ROOT / "cpuacct"))


def _cpu_over(path: str, seconds: float) -> float:
    """CPU seconds per second used below `path` over a window."""
    u0, t0 = cgroups.usage_seconds(path), time.monotonic()
    time.sleep(seconds)
    return (cgroups.usage_seconds(path) - u0) / (time.monotonic() - t0)


def test_a_pod_on_a_real_node_runs_a_real_process(
    kube: Kube, namespace: str, bed_nodes: dict[str, realnodes.RealNode]
) -> None:
    node = bed_nodes["bed-robot-1"]
    kube.apply(_pod("hello", node.name, "echo hello-from-$(hostname); sleep 3600"), namespace)
    pod = _running(kube, namespace, "hello")
    state = pod["status"]["containerStatuses"][0]["state"]
    assert "running" in state and state["running"]["startedAt"], state
    assert pod["spec"]["nodeName"] == node.name
    assert re.fullmatch(r"198\.18\.17\.\d+", pod["status"]["podIP"]), pod["status"]["podIP"]
    kube.wait_for(
        "the container's log",
        lambda: "hello-from-hello" in kube.kubectl("logs", "hello", "-n", namespace).stdout,
        30,
    )
    # the process lives in the node's cgroup, so the node's share bounds it
    assert cgroups.pids(_pod_cgroup(node, pod["metadata"]["uid"]))


def test_a_cpu_limit_is_enforced_on_a_real_node(
    kube: Kube, namespace: str, bed_nodes: dict[str, realnodes.RealNode]
) -> None:
    node = bed_nodes["bed-edge-1"]
    kube.apply(_pod("burn", node.name, "while :; do :; done", cpu="100m"), namespace)
    pod = _running(kube, namespace, "burn")
    used = _cpu_over(_pod_cgroup(node, pod["metadata"]["uid"]), 6)
    # CFS quota 10 ms per 100 ms; a busy loop uses all of it and no more
    assert 0.06 < used < 0.12, f"a busy container limited to 100m used {used:.3f} CPU"


def test_a_node_never_uses_more_than_its_share(
    kube: Kube, namespace: str, bed_nodes: dict[str, realnodes.RealNode]
) -> None:
    node = bed_nodes["bed-robot-2"]
    share = node.cpu_millis / 1000
    for i in range(2):  # no limits: together they would take two cores
        kube.apply(_pod(f"hog-{i}", node.name, "while :; do :; done"), namespace)
    for i in range(2):
        _running(kube, namespace, f"hog-{i}")
    # the share is the quota of the node's pods (its kubelet and containerd run beside it,
    # as a computer's system daemons do: e2e/bed/cgroups.py)
    used = _cpu_over(f"{node.cgroup}/pods", 6)
    assert share * 0.7 < used < share * 1.1, f"{node.name} (share {share}) used {used:.3f} CPU"
    alloc = kube.kubectl_json("get", "node", node.name)["status"]["allocatable"]
    assert alloc["cpu"] == f"{node.cpu_millis}m", alloc


def test_a_node_gets_its_share_while_the_host_is_busy(
    kube: Kube, namespace: str, bed_nodes: dict[str, realnodes.RealNode]
) -> None:
    """A node is another computer: a busy control plane (here: four spinning host processes
    per core, plus two, each in its own session like the harness's control-plane processes,
    so each is its own autogroup) does not take its CPU. Without ``/fogfleet``'s weight the
    bed's group competes like one of those processes and gets cores/(4 cores + 3) of the host:
    0.18 of a core on two cores, under 80 % of the node's 400m."""
    node = bed_nodes["bed-robot-2"]
    share = node.cpu_millis / 1000
    for i in range(2):
        kube.apply(_pod(f"hog-{i}", node.name, "while :; do :; done"), namespace)
    for i in range(2):
        _running(kube, namespace, f"hog-{i}")
    spinners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        for _ in range(4 * (os.cpu_count() or 1) + 2)
    ]
    try:
        time.sleep(1)
        used = _cpu_over(f"{node.cgroup}/pods", 6)
    finally:
        for proc in spinners:  # by pid
            proc.kill()
            proc.wait()
    assert used > share * 0.8, f"{node.name} (share {share}) got {used:.3f} CPU on a busy host"


def _ping_ms(kube: Kube, namespace: str, pod: str, ip: str, count: int = 20) -> list[float]:
    out = kube.kubectl(
        "exec", pod, "-n", namespace, "--", "ping", "-c", str(count), "-i", "0.2", "-W", "2", ip,
        check=False, timeout=60,
    ).stdout  # fmt: skip
    return [float(m) for m in re.findall(r"time=([\d.]+) ms", out)]


@pytest.fixture
def two_robots(
    kube: Kube, namespace: str, cluster: Cluster, bed_nodes: dict[str, realnodes.RealNode]
) -> Iterator[tuple[str, str]]:
    """A pod on each real robot; their links are restored to nodes.yaml's after the test."""
    for name, node in (("a", "bed-robot-1"), ("b", "bed-robot-2")):
        kube.apply(_pod(name, node, "sleep 3600"), namespace)
    _running(kube, namespace, "a")
    ip_b = _running(kube, namespace, "b")["status"]["podIP"]
    yield "a", ip_b
    for node in ("bed-robot-1", "bed-robot-2"):
        cluster.reset_link(node)


def test_round_trip_between_real_nodes_matches_the_configured_links(
    kube: Kube,
    namespace: str,
    cluster: Cluster,
    two_robots: tuple[str, str],
    bed_nodes: dict[str, realnodes.RealNode],
) -> None:
    pod, ip = two_robots
    # The delay line itself costs a little per crossing (a userspace wake-up, more on a busy
    # host): measure that floor with a negligible delay (0.1 ms keeps the delay line in the
    # path; zero would take it out) and judge only what the configured delay adds.
    for node in ("bed-robot-1", "bed-robot-2"):
        cluster.set_link(node, delay_ms=0.1, jitter_ms=0)
    floor = statistics.median(_ping_ms(kube, namespace, pod, ip)) - 4 * 0.1
    for node in ("bed-robot-1", "bed-robot-2"):
        cluster.reset_link(node)
    # each packet crosses both robots' links: one way = delay_1 + delay_2, round trip twice that
    declared = sum(bed_nodes[n].link["latencyMillis"] for n in ("bed-robot-1", "bed-robot-2"))
    cases = [("nodes.yaml's links", 2 * declared)]
    rtts = [statistics.median(_ping_ms(kube, namespace, pod, ip))]
    for delay in (10, 25):
        for node in ("bed-robot-1", "bed-robot-2"):
            cluster.set_link(node, delay_ms=delay, jitter_ms=0)
        cases.append((f"{delay} ms per link", 4 * delay))
        rtts.append(statistics.median(_ping_ms(kube, namespace, pod, ip)))
    report = f"floor {floor:.1f} ms; " + ", ".join(
        f"{c}: {r:.1f} ms (expected {e} ms + floor)" for (c, e), r in zip(cases, rtts, strict=True)
    )
    print(f"round trips: {report}")
    assert floor < 10, f"the bed's links cost {floor:.1f} ms with no delay configured"
    for (case, expected), rtt in zip(cases, rtts, strict=True):
        assert abs(rtt - floor - expected) <= 0.2 * expected + 1.0, f"{case}: {report}"


def test_a_cut_link_stops_traffic_and_restoring_it_recovers(
    kube: Kube, namespace: str, cluster: Cluster, two_robots: tuple[str, str]
) -> None:
    pod, ip = two_robots
    assert _ping_ms(kube, namespace, pod, ip, 3), "no traffic before the cut"
    cluster.set_link("bed-robot-2", loss_percent=100)
    assert _ping_ms(kube, namespace, pod, ip, 5) == [], "traffic crossed a cut link"
    cluster.reset_link("bed-robot-2")
    kube.wait_for(
        "traffic after the restore", lambda: bool(_ping_ms(kube, namespace, pod, ip, 2)), 30
    )


def test_kwok_leaves_real_nodes_to_their_kubelets(kube: Kube, cluster: Cluster) -> None:
    for name in cluster.real_nodes:
        node = kube.kubectl_json("get", "node", name)
        assert "kwok.x-k8s.io/node" not in (node["metadata"].get("annotations") or {})
        assert node["status"]["nodeInfo"]["containerRuntimeVersion"].startswith("containerd://")
        assert node["status"]["nodeInfo"]["kubeletVersion"] == "v" + cluster.versions["K8S_VERSION"]
