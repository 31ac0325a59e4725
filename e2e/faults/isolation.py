"""The fleet whose robots test_faults_network_policy keeps apart, and the probes it sends.

A lidar on each robot, a planner per robot on the edge (so each robot's traffic crosses a
link) and one shared fleet-map on the edge. The probes: a listener inside a pod's container
(TCP and UDP on PORT, which no policy of the fleet opens, and any TCP ports given), a sender
run in a pod or on the host, and the operator's NetworkPolicy and pod labels as shipped
(manifests or chart) with a stand-in pod to apply them to.
"""

from __future__ import annotations

import json
import socket
import subprocess
import threading
import time
from collections.abc import Iterable
from typing import Any

import yaml

from e2e.bed.base import HERE
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import helm
from e2e.tests.rosbed import IMAGE, bed_objects, ros_module, scrape_series

__all__ = [
    "FLEET",
    "LISTENER",
    "METRICS",
    "PORT",
    "SENDER",
    "Listener",
    "iso_fleet_objects",
    "pod_of",
    "received",
    "send",
    "send_from_host",
    "shipped",
    "standin",
]

FLEET = "isofleet"
PORT = 17000  # a port the probe listeners open and no policy of the fleet allows
METRICS = 9100
REPO = HERE.parents[1]

# Listens on TCP and UDP ``PORT`` (and any TCP ports given) for a while; prints what came.
LISTENER = r"""
import select, socket, sys, time
ports = [int(p) for p in sys.argv[2:]]
socks = []
for p in ports:
    t = socket.socket(); t.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    t.bind(("0.0.0.0", p)); t.listen(16); socks.append(t)
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); u.bind(("0.0.0.0", ports[0])); socks.append(u)
print("ready", flush=True)
end = time.time() + float(sys.argv[1])
while time.time() < end:
    for s in select.select(socks, [], [], 0.5)[0]:
        if s is u:
            print("udp", s.recvfrom(256)[0].decode(), flush=True)
        else:
            c, _ = s.accept(); c.settimeout(2)
            try:
                print("tcp", c.recv(256).decode(), flush=True)
            except OSError:
                pass
            c.close()
"""

# Sends each tag over TCP, then UDP (five datagrams 50 ms apart: the first ones to an address
# not yet resolved may wait on ARP, and UDP does not retry); prints "tcp TAG ok|fail".
SENDER = r"""
import json, socket, sys, time
for ip, port, tag in json.loads(sys.argv[1]):
    try:
        socket.create_connection((ip, port), timeout=3).sendall(tag.encode())
        print("tcp", tag, "ok", flush=True)
    except OSError as exc:
        print("tcp", tag, "fail", exc, flush=True)
    u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for _ in range(5):
        u.sendto(tag.encode(), (ip, port))
        time.sleep(0.05)
"""


def iso_fleet_objects(ns: str) -> list[dict[str, Any]]:
    modules = [
        ros_module("lidar", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[], publishes=[("scan", 1024, 10)],
                   profile=[("bed-robot", "50m", 4, 0.5)]),
        # offloaded: its robot's scan crosses the robot's link
        ros_module("planner", ns, cycle_ms=500, taxonomy=("periodic", "soft", "relevant"),
                   subscribes=[("scan", 1024, 10), ("map", 512, 2)],
                   publishes=[("plan", 512, 2)],
                   profile=[("bed-robot", "100m", 40, 4), ("bed-edge", "100m", 20, 2)],
                   tiers=["edge"]),
        # one for the fleet: hears every robot, every robot hears it
        ros_module("fleet-map", ns, cycle_ms=500, taxonomy=("periodic", "soft", "relevant"),
                   subscribes=[("scan", 1024, 10)], publishes=[("map", 512, 2)],
                   profile=[("bed-edge", "100m", 20, 2)], tiers=["edge"],
                   scope="shared", replicas=1),
    ]  # fmt: skip
    return bed_objects(ns, FLEET, modules)


class Listener:
    """A probe listener inside a pod's container (``kubectl exec``), for ``seconds``."""

    def __init__(self, kube: Kube, ns: str, pod: str, container: str, seconds: int,
                 tcp_ports: tuple[int, ...] = (PORT,)) -> None:  # fmt: skip
        argv = [kube.kubectl_bin, f"--kubeconfig={kube.kubeconfig}", "exec", pod, "-n", ns,
                "-c", container, "--", "python3", "-u", "-c", LISTENER, str(seconds),
                *map(str, tcp_ports)]  # fmt: skip
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)  # fmt: skip
        assert self.proc.stdout is not None
        first = self.proc.stdout.readline().strip()
        assert first == "ready", f"listener in {pod}: {first!r}"
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.strip())

    def _tags(self, kind: str) -> set[str]:
        return {ln.split()[1] for ln in list(self.lines) if ln.startswith(f"{kind} ")}

    def heard(self, expect_tcp: Iterable[str] = ()) -> tuple[set[str], set[str]]:
        """(UDP tags, TCP tags) it has received (its process in the pod runs on until its
        time is up; the test's namespace goes with it). ``expect_tcp``: the tags whose TCP
        connection the sender saw accepted here; they are waited for (kubectl relays them
        later on a loaded machine; 30 s only guards a hang), then one more second is a
        window for the datagrams sent beside them."""
        want = set(expect_tcp)
        deadline = time.monotonic() + 30
        while not want <= self._tags("tcp") and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1)  # an observation window for the last datagrams, not a wait
        self.proc.terminate()
        self.proc.wait(timeout=30)
        self._reader.join(timeout=30)
        return self._tags("udp"), self._tags("tcp")


def send(
    kube: Kube, ns: str, pod: dict[str, Any], probes: list[tuple[str, int, str]]
) -> dict[str, bool]:
    container = pod["spec"]["containers"][0]["name"]
    argv = ["exec", pod["metadata"]["name"], "-n", ns, "-c", container, "--",
            "python3", "-u", "-c", SENDER, json.dumps(probes)]  # fmt: skip
    out = kube.kubectl(*argv, timeout=120).stdout
    result = {
        ln.split()[1]: ln.split()[2] == "ok" for ln in out.splitlines() if ln.startswith("tcp ")
    }
    assert set(result) == {tag for _, _, tag in probes}, out
    return result


def send_from_host(probes: list[tuple[str, int, str]]) -> dict[str, bool]:
    """The host's own view (Prometheus scrapes from here, through the bed's bridge)."""
    result = {}
    for ip, port, tag in probes:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            for _ in range(3):
                u.sendto(tag.encode(), (ip, port))
        try:
            with socket.create_connection((ip, port), timeout=3) as c:
                c.sendall(tag.encode())
            result[tag] = True
        except OSError:
            result[tag] = False
    return result


def pod_of(pods: dict[str, Any], robot: str, module: str) -> dict[str, Any]:
    for pod in pods.values():
        labels = pod["metadata"]["labels"]
        if labels.get("fogfleet.io/robot") == robot and labels.get("fogfleet.io/module") == module:
            return pod
    raise AssertionError(f"no {module} pod of robot {robot!r}")


def received(pod: dict[str, Any], topic: str) -> float:
    url = f"http://{pod['status']['podIP']}:{METRICS}/metrics"
    return scrape_series(url, "fogfleet_messages_received_total", topic=topic)


def shipped(source: str) -> tuple[dict[str, Any], dict[str, str], tuple[int, int]]:
    """(NetworkPolicy, the operator pod's labels, (probe port, metrics port)) as shipped."""
    if source == "manifests":
        install = REPO / "manifests" / "install"
        docs = [d for f in sorted(install.glob("*.yaml"))
                for d in yaml.safe_load_all(f.read_text()) if d]  # fmt: skip
    else:
        out = helm("template", "fogfleet", str(REPO / "charts" / "fogfleet"),
                   "--namespace", "fogfleet-system")  # fmt: skip
        docs = [d for d in yaml.safe_load_all(out) if d]
    (policy,) = [d for d in docs if d["kind"] == "NetworkPolicy"]
    (dep,) = [d for d in docs if d["kind"] == "Deployment"]
    labels = dep["spec"]["template"]["metadata"]["labels"]
    (container,) = dep["spec"]["template"]["spec"]["containers"]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    probe = next(v for k, v in ports.items() if k != "metrics")
    return policy, labels, (probe, ports["metrics"])


def standin(name: str, node: str, labels: dict[str, str], command: list[str]) -> dict[str, Any]:
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": name, "labels": labels},
        "spec": {
            "nodeSelector": {"kubernetes.io/hostname": node},
            "automountServiceAccountToken": False,
            "terminationGracePeriodSeconds": 1,
            "tolerations": [{"key": "fogfleet.io/dedicated", "operator": "Exists"}],
            "containers": [{
                "name": "main", "image": IMAGE, "imagePullPolicy": "Never", "command": command,
                "resources": {"requests": {"cpu": "10m", "memory": "32Mi"}},
                "securityContext": {"allowPrivilegeEscalation": False, "runAsNonRoot": True,
                                    "runAsUser": 65532, "capabilities": {"drop": ["ALL"]}},
            }],
        },
    }  # fmt: skip
