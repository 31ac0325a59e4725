"""The fleet whose discovery server test_faults_discovery fails, reading its modules, and
killing a container's process by pid.

Each robot runs a camera and a safety module on board and a detector on the edge; FLOWS lists
what flows between them. Here are the fleet's objects; one scrape of a module (received and
published per topic, cycles, misses, input gaps), every module read at once, and the losses
and missed cycles between two such snapshots; the robot's discovery server, its pod and its
Service address; and a container's process killed through its node's containerd: once, over
and over (a crash loop), or a module's until it talks again.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import time
import urllib.request
from functools import partial
from pathlib import Path
from typing import Any

from e2e.bed import realnodes
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import pods_by_instance
from e2e.faults.cost import metrics_url, scraped, skew_messages
from e2e.tests.rosbed import ROBOTS, bed_objects, ros_module
from fogfleet.render.names import discovery_service_name

__all__ = [
    "FLEET",
    "FLOWS",
    "RATE_HZ",
    "REJOIN_S",
    "crash_loop",
    "discovery_service_ip",
    "ds_fleet_objects",
    "flow_losses",
    "flowing",
    "kill",
    "kill_and_rejoin",
    "missed_cycles",
    "module_pods",
    "ready",
    "restart_count",
    "server_pod",
    "snapshot",
]

FLEET = "dsfleet"
RATE_HZ = 10
REJOIN_S = 45  # a killed module's process restarted until its inputs and outputs flow again

# (consumer module, topic, producer module) of each robot
FLOWS = (
    ("safety", "image", "camera"),  # on board
    ("detector", "image", "camera"),  # robot -> edge
    ("safety", "objects", "detector"),  # edge -> robot
)


def ds_fleet_objects(ns: str) -> list[dict[str, Any]]:
    modules = [
        ros_module("camera", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[], publishes=[("image", 2048, RATE_HZ)],
                   profile=[("bed-robot", "50m", 3, 0.3)]),
        ros_module("detector", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=[("image", 2048, RATE_HZ)], publishes=[("objects", 256, RATE_HZ)],
                   profile=[("bed-edge", "50m", 5, 0.5)], tiers=["edge"]),
        ros_module("safety", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[("image", 2048, RATE_HZ), ("objects", 256, RATE_HZ)],
                   publishes=[("stop", 64, RATE_HZ)], profile=[("bed-robot", "50m", 3, 0.3)]),
    ]  # fmt: skip
    for m in modules:
        m["spec"]["resources"]["memory"] = "192Mi"
    return bed_objects(ns, FLEET, modules)


# --------------------------------------------------------------------------------------------
# reading the modules


def _series(url: str) -> list[tuple[str, dict[str, str], float]]:
    text = urllib.request.urlopen(url, timeout=5).read().decode()
    out = []
    for line in text.splitlines():
        m = re.match(r"^(\w+)(?:\{([^}]*)\})?\s+([0-9.eE+-]+|\+Inf)$", line)
        if m:
            labels = dict(re.findall(r'(\w+)="([^"]*)"', m.group(2) or ""))
            out.append((m.group(1), labels, float(m.group(3))))
    return out


def _read(url: str) -> dict[Any, float]:
    """One scrape of a module: received/published per topic, cycles, misses, input gaps."""
    out: dict[Any, float] = {}
    for name, labels, value in _series(url):
        topic = labels.get("topic", "")
        if name == "fogfleet_messages_received_total":
            out[("recv", topic)] = value
        elif name == "fogfleet_messages_published_total":
            out[("pub", topic)] = value
        elif name == "fogfleet_missed_cycles_total":
            out["missed"] = out.get("missed", 0.0) + value
        elif name == "fogfleet_cycle_time_seconds_count":
            out["cycles"] = out.get("cycles", 0.0) + value
        elif name == "fogfleet_input_gap_seconds_bucket":
            out[("gap", topic, float(labels["le"]))] = value
        elif name == "fogfleet_foreign_messages_total":
            out["foreign"] = out.get("foreign", 0.0) + value
    return out


def module_pods(kube: Kube, ns: str) -> dict[tuple[str, str], Any]:
    """(robot, module) -> its running pod."""
    out = {}
    for pod in pods_by_instance(kube, ns).values():
        labels = pod["metadata"]["labels"]
        out[(labels["fogfleet.io/robot"], labels["fogfleet.io/module"])] = pod
    return out


def snapshot(urls: dict[tuple[str, str], str]) -> dict[tuple[str, str], dict[Any, float]]:
    """Every module read once, producers before consumers; ``"at"``: when each was read
    (``flow_losses`` takes out what the moments between the reads account for)."""
    order = sorted(urls, key=lambda rm: ("camera", "detector", "safety").index(rm[1]))
    out = {}
    for rm in order:
        counters, at = scraped(partial(_read, urls[rm]))
        out[rm] = {**counters, "at": at}
    return out


def _received(url: str, topic: str) -> float:
    try:
        return _read(url).get(("recv", topic), 0.0)
    except OSError:  # a restarted process whose metrics server is not up yet
        return -1.0


def _published(url: str, topic: str) -> float:
    try:
        return _read(url).get(("pub", topic), 0.0)
    except OSError:
        return -1.0


def flowing(urls: dict[tuple[str, str], str], robots: tuple[str, ...]) -> bool:
    """Every input of every module of ``robots`` got 5 more messages within 2 s."""
    keys = [(r, c, t) for r in robots for c, t, _ in FLOWS]
    first = {k: _received(urls[(k[0], k[1])], k[2]) for k in keys}
    if min(first.values()) < 0:
        return False
    time.sleep(2)
    return all(_received(urls[(k[0], k[1])], k[2]) >= first[k] + 5 for k in keys)


def flow_losses(
    before: dict[tuple[str, str], dict[Any, float]], after: dict[tuple[str, str], dict[Any, float]]
) -> dict[str, dict[str, float]]:
    """Per flow of every robot: messages published, received, lost (less what the moments of
    the reads account for: ``cost.skew_messages``), and the longest gap (the smallest
    histogram bound that holds every gap since ``before``)."""
    out = {}
    for robot in ROBOTS:
        for consumer, topic, producer in FLOWS:
            p0, p1 = before[(robot, producer)], after[(robot, producer)]
            c0, c1 = before[(robot, consumer)], after[(robot, consumer)]
            sent = p1[("pub", topic)] - p0[("pub", topic)]
            got = c1[("recv", topic)] - c0[("recv", topic)]
            skew = skew_messages(sent, (p0["at"], p1["at"]), (c0["at"], c1["at"]))
            gaps = {k[2]: v - c0.get(k, 0.0) for k, v in c1.items() if k[:2] == ("gap", topic)}
            longest = min(le for le, n in gaps.items() if n == gaps[math.inf])
            out[f"{robot}/{producer}->{consumer}:{topic}"] = {
                "sent": sent, "received": got, "lost": max(0.0, round(sent - got - skew)),
                "longestGap": longest, "scrapeSkew": round(skew, 1),
            }  # fmt: skip
    return out


def missed_cycles(
    before: dict[tuple[str, str], dict[Any, float]],
    after: dict[tuple[str, str], dict[Any, float]],
    robot: str,
) -> tuple[float, float]:
    """(cycles run, cycles missed) by ``robot``'s modules between the two snapshots."""
    keys = [k for k in after if k[0] == robot]
    cycles = sum(after[k].get("cycles", 0) - before[k].get("cycles", 0) for k in keys)
    missed = sum(after[k].get("missed", 0) - before[k].get("missed", 0) for k in keys)
    return cycles, missed


# --------------------------------------------------------------------------------------------
# the discovery server and killing processes


def server_pod(kube: Kube, ns: str, robot: str) -> Any | None:
    """The robot's discovery server pod that is not being deleted (None: none yet)."""
    items = kube.kubectl_json(
        "get", "pods", "-n", ns, "-l",
        f"app.kubernetes.io/component=ros-discovery-server,fogfleet.io/robot={robot}",
    )["items"]  # fmt: skip
    live = [p for p in items if not p["metadata"].get("deletionTimestamp")]
    return live[0] if live else None


def ready(pod: Any | None) -> bool:
    conds = ((pod or {}).get("status") or {}).get("conditions") or []
    return any(c["type"] == "Ready" and c["status"] == "True" for c in conds)


def restart_count(pod: Any) -> int:
    return sum(s.get("restartCount", 0) for s in pod["status"].get("containerStatuses", []))


def _container_pid(pod: Any) -> int:
    """The host pid of the pod's (first) container's main process, from its node's containerd."""
    (status,) = pod["status"]["containerStatuses"][:1]
    cid = status["containerID"].removeprefix("containerd://")
    socket = realnodes.declared(pod["spec"]["nodeName"]).socket
    out = subprocess.run(
        [realnodes.CTR, f"--address={socket}", "-n", "k8s.io", "tasks", "ls"],
        capture_output=True, text=True, check=True, timeout=30,
    ).stdout  # fmt: skip
    for line in out.splitlines():
        parts = line.split()
        if parts and parts[0] == cid and parts[2] == "RUNNING":
            pid = int(parts[1])
            # the pid is that container's: its cgroup path names the container
            assert cid in Path(f"/proc/{pid}/cgroup").read_text()
            return pid
    raise AssertionError(f"no running task {cid} in {pod['spec']['nodeName']}'s containerd")


def kill(pod: Any) -> int:
    pid = _container_pid(pod)
    os.kill(pid, signal.SIGKILL)
    return pid


def crash_loop(kube: Kube, ns: str, robot: str, seconds: float) -> int:
    """Kill the robot's discovery server's process, and again each time the kubelet starts
    it, until it has been down ``seconds``; returns how many times it was killed."""
    t0 = time.monotonic()
    killed: set[int] = set()
    while time.monotonic() - t0 < seconds:
        pod = server_pod(kube, ns, robot)
        try:
            pid = _container_pid(pod) if pod is not None else None
        except (AssertionError, OSError, subprocess.CalledProcessError):
            pid = None  # between two runs of the container
        if pid is not None and pid not in killed:
            os.kill(pid, signal.SIGKILL)
            killed.add(pid)
        time.sleep(0.1)
    return len(killed)


def discovery_service_ip(kube: Kube, ns: str, robot: str) -> str:
    svc = kube.kubectl_json("get", "service", "-n", ns, discovery_service_name(FLEET, robot))
    return str(svc["spec"]["clusterIP"])


def kill_and_rejoin(kube: Kube, ns: str, robot: str, module: str) -> float:
    """Kill ``module``'s process on ``robot`` (the kubelet restarts it in its pod): seconds
    until the new participant receives every input and its consumers receive its outputs,
    all matched through the (restarted) discovery server."""
    pod = module_pods(kube, ns)[(robot, module)]
    url = metrics_url(pod)
    restarts = restart_count(pod)
    kill(pod)
    t0 = time.monotonic()
    kube.wait_for(
        f"{robot}'s {module} restarted",
        lambda: restart_count(module_pods(kube, ns)[(robot, module)]) > restarts,
        REJOIN_S,
        interval=0.5,
    )
    inputs = [t for c, t, _ in FLOWS if c == module]
    consumers = [(c, t) for c, t, p in FLOWS if p == module]
    pods = module_pods(kube, ns)
    then = {(c, t): _received(metrics_url(pods[(robot, c)]), t) for c, t in consumers}

    def talks() -> bool:
        return (
            all(_received(url, t) > 5 for t in inputs)
            and all(_published(url, t) > 5 for _, t in consumers)
            and all(
                _received(metrics_url(pods[(robot, c)]), t) > then[(c, t)] + 5 for c, t in consumers
            )
        )

    kube.wait_for(f"{robot}'s restarted {module} talking again", talks, REJOIN_S, interval=0.5)
    return time.monotonic() - t0
