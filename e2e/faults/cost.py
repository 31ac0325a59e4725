"""What a fault cost a running ROS 2 fleet, from its workloads' own counters: messages lost
on each flow, cycles missed, and whether any of its pods was re-created or restarted. Shared
by the fault tests (issue 37); the fleet is ``rosbed.split_fleet``.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Self, TypeVar

from e2e.bed.base import wait_for
from e2e.bed.kube import Kube
from e2e.faults.record import FaultResult, record_measured
from e2e.portable.metrics import read
from fogfleet.api.labels import ANNOTATION_PLAN
from fogfleet.contract.env import METRICS_PORT

__all__ = [
    "FLOWS", "NodeHistory", "Poller", "Snapshot", "fault_result", "metrics_url", "scraped",
    "skew_messages", "snapshot",
]  # fmt: skip

T = TypeVar("T")

# (producer, topic, consumer) of rosbed.split_fleet, per robot
FLOWS = (("lidar", "scan", "localizer"), ("localizer", "pose", "planner"))


def metrics_url(pod: Any) -> str:
    """A module pod's metrics endpoint (the workload contract's port)."""
    return f"http://{pod['status']['podIP']}:{METRICS_PORT}/metrics"


@dataclass(frozen=True)
class Snapshot:
    """One scrape of every module pod of a fleet: per (robot, module) its counters, and its
    pod's uid and container restarts (a re-created or restarted pod shows here); ``at``: when
    each pod was scraped (time.monotonic(), the middle of its request)."""

    counters: dict[tuple[str, str], dict[str, float]]
    pods: dict[tuple[str, str], tuple[str, int]]
    at: dict[tuple[str, str], float] = field(default_factory=dict)

    def messages_lost(self, later: Snapshot) -> int:
        """Messages published on a flow since this snapshot and not received: per flow and
        robot, the producer's published minus the consumer's received, less what only the
        moments of the scrapes account for (``skew_messages``); never below 0."""
        lost = 0.0
        for robot in {r for r, _ in self.counters}:
            for producer, topic, consumer in FLOWS:
                p, c = (robot, producer), (robot, consumer)
                sent = _delta(self, later, p, f"published:{topic}")
                got = _delta(self, later, c, f"received:{topic}")
                skew = 0.0
                if {p, c} <= self.at.keys() & later.at.keys():
                    skew = skew_messages(sent, (self.at[p], later.at[p]), (self.at[c], later.at[c]))
                lost += max(0.0, sent - got - skew)
        return round(lost)

    def cycles_missed(self, later: Snapshot) -> int:
        return round(sum(_delta(self, later, key, "missed") for key in self.counters))

    def missed_by_module(self, later: Snapshot) -> dict[str, int]:
        """Cycles missed since this snapshot per robot/module, those that missed any."""
        missed = {(r, m): round(_delta(self, later, (r, m), "missed")) for r, m in self.counters}
        return {f"{r}/{m}": n for (r, m), n in sorted(missed.items()) if n}

    def cycles(self, later: Snapshot) -> int:
        return round(sum(_delta(self, later, key, "cycles") for key in self.counters))

    def replaced(self, later: Snapshot) -> list[str]:
        """The module pods re-created or restarted since this snapshot."""
        return [f"{r}/{m}" for (r, m), pod in self.pods.items() if later.pods.get((r, m)) != pod]


def _delta(a: Snapshot, b: Snapshot, key: tuple[str, str], name: str) -> float:
    return b.counters.get(key, {}).get(name, 0.0) - a.counters.get(key, {}).get(name, 0.0)


def skew_messages(
    sent: float, producer: tuple[float, float], consumer: tuple[float, float]
) -> float:
    """Messages a flow seems to lose (negative: to gain) only because its producer and its
    consumer were scraped at different moments: ``producer`` and ``consumer`` are the times
    of their first and second scrapes. A consumer scraped 0.3 s after its producer at the
    first snapshot and right after it at the second has counted 0.3 s of messages the
    producer's delta does not hold; on a loaded machine the scrapes of a snapshot spread
    out, so the raw difference would measure the machine's load, not the flow. The
    producer's rate is its own: ``sent`` over the time between its scrapes."""
    span = producer[1] - producer[0]
    if span <= 0:
        return 0.0
    return sent / span * ((consumer[0] - producer[0]) - (consumer[1] - producer[1]))


def scraped(read: Callable[[], T]) -> tuple[T, float]:
    """``read()`` and when it read: the middle of the call (time.monotonic())."""
    t0 = time.monotonic()
    value = read()
    return value, (t0 + time.monotonic()) / 2


def _counters(url: str) -> dict[str, float]:
    """A module pod's message and cycle counters: ``published:TOPIC``, ``received:TOPIC``,
    ``missed`` and ``cycles``."""
    out: dict[str, float] = {}
    for name, labels, value in read(url).series:
        key = {
            "fogfleet_messages_published_total": f"published:{labels.get('topic')}",
            "fogfleet_messages_received_total": f"received:{labels.get('topic')}",
            "fogfleet_missed_cycles_total": "missed",
            "fogfleet_cycle_time_seconds_count": "cycles",
        }.get(name)
        if key:
            out[key] = out.get(key, 0.0) + value
    return out


def snapshot(kube: Kube, namespace: str, fleet: str) -> Snapshot:
    """Scrape every running module pod of ``fleet`` (not its standbys or discovery server)."""
    items = kube.kubectl_json(
        "get", "pods", "-n", namespace, "-l", f"fogfleet.io/fleet={fleet},fogfleet.io/instance"
    )["items"]
    counters: dict[tuple[str, str], dict[str, float]] = {}
    pods: dict[tuple[str, str], tuple[str, int]] = {}
    at: dict[tuple[str, str], float] = {}
    for pod in items:
        meta, status = pod["metadata"], pod.get("status") or {}
        if meta.get("deletionTimestamp") or status.get("phase") != "Running":
            continue
        key = (meta["labels"]["fogfleet.io/robot"], meta["labels"]["fogfleet.io/module"])
        restarts = sum(c.get("restartCount", 0) for c in status.get("containerStatuses") or [])
        pods[key] = (meta["uid"], restarts)
        counters[key], at[key] = scraped(partial(_counters, metrics_url(pod)))
    return Snapshot(counters, pods, at)


def fault_result(fault: str, **fields: Any) -> FaultResult:
    """Record what a fault cost (``e2e.faults.record``: printed, and kept for
    docs/survives.md when ``make test-faults`` runs)."""
    return record_measured({"fault": fault, **fields})


class Poller:
    """Calls ``poll()`` every ``interval`` seconds in a thread while used as a context
    manager (``t0``: when it started); a fault test's view of the cluster during the fault."""

    def __init__(self, interval: float) -> None:
        self.interval = interval
        self.t0 = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Self:
        self.t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join(10)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.poll()
            self._stop.wait(self.interval)

    def poll(self) -> None:
        raise NotImplementedError


class NodeHistory(Poller):
    """Where each instance's pod ran, polled every ``interval`` seconds in a thread: per
    instance (its fogfleet.io/instance label), the nodes in the order its pods were bound to
    them. ``moves()`` counts how often an instance changed node; ``plans`` says which plan
    moved it: the plan id on the instance's Deployment (named as the instance) when the
    poll first saw its pod on the new node (the pod follows its Deployment's update)."""

    def __init__(self, kube: Kube, namespace: str, selector: str, interval: float = 0.5) -> None:
        from kubernetes import client

        super().__init__(interval)
        self.nodes: dict[str, list[str]] = {}
        self.plans: dict[str, list[str]] = {}  # per instance, the plan of each node it ran on
        self.polls = 0
        self.errors = 0
        self._api = client.CoreV1Api(kube.api_client())
        self._apps = client.AppsV1Api(kube.api_client())
        self._namespace, self._selector = namespace, selector

    def _list(self, call: Callable[..., Any]) -> list[dict[str, Any]]:
        resp = call(self._namespace, label_selector=self._selector, _preload_content=False)
        items: list[dict[str, Any]] = json.loads(resp.data)["items"]
        return items

    def poll(self) -> None:
        try:
            pods = self._list(self._api.list_namespaced_pod)
            deployments = self._list(self._apps.list_namespaced_deployment)
        except Exception:  # the API may be away (a fault): poll again
            self.errors += 1
            return
        plan_of = {
            d["metadata"]["name"]: (d["metadata"].get("annotations") or {}).get(ANNOTATION_PLAN, "")
            for d in deployments
        }
        newest: dict[str, str] = {}  # per instance, the node of its newest bound pod
        for pod in sorted(pods, key=lambda p: str(p["metadata"]["creationTimestamp"])):
            meta, node = pod["metadata"], pod["spec"].get("nodeName")
            instance = (meta.get("labels") or {}).get("fogfleet.io/instance")
            if instance and node and not meta.get("deletionTimestamp"):
                newest[instance] = node
        for instance, node in newest.items():
            seen = self.nodes.setdefault(instance, [])
            if not seen or seen[-1] != node:
                seen.append(node)
                self.plans.setdefault(instance, []).append(plan_of.get(instance, ""))
        self.polls += 1  # once what it saw is in ``nodes`` (``caught_up`` counts on it)

    def caught_up(self, timeout: float = 60) -> None:
        """Return once a poll begun after this call has completed: the history holds where
        every pod is now (a fixed sleep would not, when a loaded API server answers a poll
        slower than the sleep)."""
        start = self.polls  # a poll under way began before this call: wait for the next one
        wait_for("a fresh poll of the pods", lambda: self.polls >= start + 2, timeout, 0.1)

    def moves(self) -> dict[str, int]:
        """Instance -> times its pod changed node (0: it stayed where it was first bound)."""
        return {i: len(nodes) - 1 for i, nodes in self.nodes.items()}

    def moved_twice_by_one_plan(self) -> dict[str, list[str]]:
        """The instances one plan moved more than once (instance -> its plans, in order)."""
        return {
            i: plans
            for i, plans in self.plans.items()
            if any(n > 1 for n in Counter(plans[1:]).values())
        }
