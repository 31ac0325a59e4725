"""Fake nodes: Node objects that kwok plays (heartbeats, pod phases); nothing runs on them."""

from __future__ import annotations

import json
import time
from typing import Any

from e2e.bed.base import NODES_FILE, HarnessError, log, wait_for
from e2e.bed.cluster import Cluster, condition_status, running

# Nothing runs on a fake node, so nothing but the pods fogfleet plans (which tolerate the key)
# may be bound to one: the operator installed as the README says lands on a real node.
# The key is fogfleet.api.labels.DEDICATED_TAINT_KEY (the harness imports only the standard
# library; test_harness checks the two agree).
SIMULATED_TAINT = {"key": "fogfleet.io/dedicated", "value": "simulated", "effect": "NoSchedule"}


def node_object(
    name: str, tier: str, hardware: str, cpu: int, memory_gi: int, robot: str | None = None
) -> dict[str, Any]:
    """A fake Node as in nodes.yaml (kwok fills conditions and addresses)."""
    labels = {
        "kubernetes.io/hostname": name,
        "kubernetes.io/os": "linux",
        "kubernetes.io/arch": "amd64",
        "fogfleet.io/tier": tier,
        "fogfleet.io/hardware-type": hardware,
    }
    if robot is not None:
        labels["fogfleet.io/robot"] = robot
    resources = {"cpu": str(cpu), "memory": f"{memory_gi}Gi", "pods": "110"}
    return {
        "apiVersion": "v1",
        "kind": "Node",
        "metadata": {
            "name": name,
            "labels": labels,
            "annotations": {"kwok.x-k8s.io/node": "fake", "node.alpha.kubernetes.io/ttl": "0"},
        },
        "spec": {"taints": [dict(SIMULATED_TAINT)]},
        "status": {"allocatable": resources, "capacity": dict(resources)},
    }


def generated_nodes(robots: int, edges: int, cloud: int) -> list[dict[str, Any]]:
    """robot-1..N (robot-nuc), edge-1..M (first half dsv3-16, rest fsv2-8), cloud-1..K."""
    out = [
        node_object(f"robot-{i}", "robot", "robot-nuc", 8, 16, robot=f"robot-{i}")
        for i in range(1, robots + 1)
    ]
    big = (edges + 1) // 2
    for i in range(1, edges + 1):
        if i <= big:
            out.append(node_object(f"edge-{i}", "edge", "dsv3-16", 16, 64))
        else:
            out.append(node_object(f"edge-{i}", "edge", "fsv2-8", 8, 16))
    out += [node_object(f"cloud-{i}", "cloud", "fsv2-32", 32, 128) for i in range(1, cloud + 1)]
    return out


def only_simulated_taint(node: dict[str, Any]) -> bool:
    """No taint but the bed's own: not NotReady, unreachable or cordoned."""
    return all(t == SIMULATED_TAINT for t in node.get("spec", {}).get("taints") or [])


def ready_nodes(items: list[dict[str, Any]]) -> set[str]:
    """The names of the Nodes in ``items`` that are Ready with no taint but the bed's."""
    return {
        node["metadata"]["name"]
        for node in items
        if condition_status(node, "Ready") == "True" and only_simulated_taint(node)
    }


def _nodes_ready(cluster: Cluster, names: set[str]) -> bool:
    return names <= ready_nodes(cluster.kubectl_json("get", "nodes")["items"])


def _apply_nodes(cluster: Cluster, manifest: str, timeout: float = 120) -> list[str]:
    out = cluster.kubectl("apply", "-f", "-", "-o", "name", input=manifest).stdout
    names = {line.split("/", 1)[1] for line in out.split() if line.startswith("node/")}
    t0 = time.monotonic()
    what = f"{len(names)} nodes Ready with no taint but the bed's"
    wait_for(what, lambda: _nodes_ready(cluster, names), timeout)
    log(f"{len(names)} nodes Ready (no taint but the bed's) after {time.monotonic() - t0:.1f}s")
    return sorted(names)


def create_nodes(robots: int | None = None, edges: int | None = None, cloud: int = 1) -> list[str]:
    """Replace every fake Node with a generated set (or nodes.yaml's when no counts are given).

    Real nodes stay as they are.
    """
    from e2e.bed.realnodes import split_manifest

    cluster = running()
    if cluster is None:
        raise HarnessError("the cluster is not running; run `harness.py up` first")
    if robots is None and edges is None:
        items, _ = split_manifest(NODES_FILE.read_text())
    else:
        items = generated_nodes(robots or 0, edges or 0, cloud)
    manifest = json.dumps({"apiVersion": "v1", "kind": "List", "items": items})
    # only the fake ones: a real node's kubelet registers its Node once, at start
    cluster.kubectl("delete", "nodes", "-l", "!fogfleet.io/e2e-real", "--wait=true", timeout=300)
    return _apply_nodes(cluster, manifest, timeout=300)
