"""The fleet whose nodes test_faults_node fails, and reading what its modules count.

Each robot runs a camera and a safety module on board and a detector on the edge node (edge
only): camera -> image -> detector -> objects -> safety, RATE_HZ each. Here are the fleet's
objects; each module's pod and what a restart or a re-creation changes of it; the workloads'
own counters (messages, missed cycles) and what was lost between two readings; whether
everything runs where planned; and the fleet's Ready condition polled while a fault lasts
(ReadyWatch).
"""

from __future__ import annotations

import time
from typing import Any

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import all_pods, conditions, fleet
from e2e.faults.cost import Poller, metrics_url
from e2e.tests.rosbed import ROBOTS, bed_objects, ros_module, scrape_series

__all__ = [
    "FLEET",
    "RATE_HZ",
    "ReadyWatch",
    "all_flowing",
    "all_where_planned",
    "baseline",
    "counter",
    "discovery_servers",
    "identity",
    "lost_objects",
    "missed_cycles",
    "module_pods",
    "node_fleet_objects",
    "read",
]

FLEET = "nodefleet"
RATE_HZ = 10


def node_fleet_objects(ns: str) -> list[dict[str, Any]]:
    image, objects = [("image", 4096, RATE_HZ)], [("objects", 512, RATE_HZ)]
    modules = [
        ros_module("camera", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[], publishes=image, profile=[("bed-robot", "50m", 3, 0.3)]),
        ros_module("detector", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=image, publishes=objects,
                   profile=[("bed-edge", "100m", 10, 1)], tiers=["edge"]),
        ros_module("safety", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=objects, publishes=[("stop", 64, RATE_HZ)],
                   profile=[("bed-robot", "50m", 3, 0.3)]),
    ]  # fmt: skip
    for m in modules:
        m["spec"]["resources"]["memory"] = "192Mi"
    return bed_objects(ns, FLEET, modules)


# --------------------------------------------------------------------------------------------
# what the test reads


def module_pods(kube: Kube, ns: str) -> dict[tuple[str, str], dict[str, Any]]:
    """(robot, module) -> its pod (not terminating), the robots' discovery servers apart."""
    out = {}
    for pod in all_pods(kube, ns):
        labels = pod["metadata"].get("labels") or {}
        if pod["metadata"].get("deletionTimestamp") or "fogfleet.io/module" not in labels:
            continue
        out[(labels["fogfleet.io/robot"], labels["fogfleet.io/module"])] = pod
    return out


def identity(pod: dict[str, Any]) -> dict[str, Any]:
    """What a restart or a re-creation changes: the pod's UID, its containers and restarts."""
    statuses = (pod.get("status") or {}).get("containerStatuses") or []
    return {
        "uid": pod["metadata"]["uid"],
        "node": pod["spec"].get("nodeName"),
        "containers": sorted(str(c.get("containerID")) for c in statuses),
        "restarts": sum(int(c.get("restartCount", 0)) for c in statuses),
    }


def counter(pod: dict[str, Any], name: str, **labels: str) -> float:
    return scrape_series(metrics_url(pod), name, **labels)


def all_where_planned(kube: Kube, ns: str) -> bool:
    """Every planned instance has a Ready pod on its planned node, and the fleet is Ready."""
    obj = fleet(kube, ns, FLEET)
    if conditions(obj).get("Ready", {}).get("status") != "True":
        return False
    planned = {(p["robot"], p["module"]): p["node"] for p in obj["status"]["placement"]}
    pods = module_pods(kube, ns)
    for key, node in planned.items():
        pod = pods.get(key)
        if pod is None or pod["spec"].get("nodeName") != node:
            return False
        conds = {c["type"]: c["status"] for c in (pod.get("status") or {}).get("conditions") or []}
        if conds.get("Ready") != "True":
            return False
    return True


def all_flowing(kube: Kube, ns: str) -> bool:
    """Objects arrive at every robot's safety module (its metrics endpoint answering)."""
    pods = module_pods(kube, ns)
    try:
        return all(
            counter(pods[(r, "safety")], "fogfleet_messages_received_total", topic="objects") > 30
            for r in ROBOTS
        )
    except (OSError, KeyError):
        return False


class ReadyWatch(Poller):
    """The fleet's Ready condition, polled every ``interval`` s in a thread: how long it was
    not Ready (first to last such sample) and what its messages said meanwhile."""

    def __init__(self, kube: Kube, ns: str, nodes: tuple[str, ...] = (), interval: float = 1.0):
        super().__init__(interval)
        self.kube, self.ns, self.nodes = kube, ns, nodes
        self.samples: list[tuple[float, str, str, str]] = []  # (t, status, reason, message)
        self.node_samples: list[tuple[float, str, str]] = []  # (t, node, its Ready status)

    def poll(self) -> None:
        try:
            c = conditions(fleet(self.kube, self.ns, FLEET)).get("Ready", {})
            sample = (time.monotonic() - self.t0, c.get("status", "?"), c.get("reason", ""),
                      c.get("message", ""))  # fmt: skip
            self.samples.append(sample)
            for node in self.nodes:
                obj = self.kube.kubectl_json("get", "node", node)
                ready = conditions(obj).get("Ready", {}).get("status", "?")
                self.node_samples.append((time.monotonic() - self.t0, node, ready))
        except Exception as exc:  # an unanswered poll is a sample too
            self.samples.append((time.monotonic() - self.t0, "?", "Unreadable", str(exc)))

    def not_ready_seconds(self) -> float:
        bad = [t for t, status, _, _ in self.samples if status != "True"]
        return (bad[-1] - bad[0] + self.interval) if bad else 0.0

    def node_not_ready(self) -> list[tuple[float, str, str]]:
        return [sample for sample in self.node_samples if sample[2] != "True"]

    def messages(self) -> list[str]:
        return sorted({f"{r}: {m}" for _, s, r, m in self.samples if s != "True"})


def baseline(kube: Kube, ns: str, seconds: float = 10) -> dict[str, Any]:
    """The counters now, and each safety module's objects rate over ``seconds``."""
    pods = module_pods(kube, ns)
    safety = {r: pods[(r, "safety")] for r in ROBOTS}
    first = {r: counter(p, "fogfleet_messages_received_total", topic="objects")
             for r, p in safety.items()}  # fmt: skip
    t0 = time.monotonic()
    time.sleep(seconds)
    return {"rate": {r: (counter(p, "fogfleet_messages_received_total", topic="objects")
                         - first[r]) / (time.monotonic() - t0) for r, p in safety.items()},
            **read(pods)}  # fmt: skip


def read(pods: dict[tuple[str, str], dict[str, Any]]) -> dict[str, Any]:
    """Per robot: objects received at its safety module, images sent by its camera and
    received by its detector, and every module's missed cycles (None: not answering)."""

    def get(pod: dict[str, Any], name: str, **labels: str) -> float | None:
        try:
            return counter(pod, name, **labels)
        except OSError:
            return None

    out: dict[str, Any] = {"t": time.monotonic(), "missed": {}}
    for r in ROBOTS:
        out[f"objects_at_{r}"] = get(pods[(r, "safety")], "fogfleet_messages_received_total",
                                     topic="objects")  # fmt: skip
        out[f"images_from_{r}"] = get(pods[(r, "camera")], "fogfleet_messages_published_total",
                                      topic="image")  # fmt: skip
        out[f"images_at_{r}"] = get(pods[(r, "detector")], "fogfleet_messages_received_total",
                                    topic="image")  # fmt: skip
        for m in ("camera", "detector", "safety"):
            out["missed"][f"{r}/{m}"] = get(pods[(r, m)], "fogfleet_missed_cycles_total")
    return out


def missed_cycles(before: dict[str, Any], after: dict[str, Any], modules: set[str]) -> int:
    return int(sum(after["missed"][k] - before["missed"][k] for k in before["missed"]
                   if k.split("/")[1] in modules))  # fmt: skip


def lost_objects(before: dict[str, Any], after: dict[str, Any], rate: dict[str, float]) -> int:
    """Objects the safety modules did not get over the window, at their baseline rate."""
    dt = after["t"] - before["t"]
    return int(sum(max(0.0, rate[r] * dt - (after[f"objects_at_{r}"] - before[f"objects_at_{r}"]))
                   for r in ROBOTS))  # fmt: skip


def discovery_servers(kube: Kube, ns: str) -> dict[str, dict[str, Any]]:
    """The robots' discovery server pods (pod name -> identity)."""
    return {
        p["metadata"]["name"]: identity(p)
        for p in all_pods(kube, ns)
        if "fogfleet.io/module" not in (p["metadata"].get("labels") or {})
        and not p["metadata"].get("deletionTimestamp")
    }
