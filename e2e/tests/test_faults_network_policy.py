"""Robot isolation enforced by the network (issue 37, item 9), on the bed's real nodes.

The bed's nodes enforce NetworkPolicy (kube-router's firewall in each node's namespace,
realnodes.py). A fleet of two robots runs a lidar on each robot, a planner per robot on the
edge (so each robot's traffic crosses a link) and one shared ``fleet-map`` on the edge. The
operator renders the fleet's policies (``render.ros.fleet_network_policies``). The planned
flows work: each planner hears its own robot's lidar across the link, the shared map hears
the robots and the planners hear the map. Then listeners started inside robot-2's pods (UDP
and TCP on a port no policy opens) are probed from every other pod with their addresses: a
pod of robot-1 reaches none of them, over the bridge of a shared node or across nodes, while
robot-2's own pods and the shared service do. The host (where Prometheus runs) reaches the
metrics port only.

The shipped operator NetworkPolicy (manifests/install and the chart) is applied the same way
to a stand-in pod with the operator's labels and ports, listening on its probe port, its
metrics port and one more: only the first two are reachable, and its egress stays open.

    pytest e2e/tests/test_faults_network_policy.py --with-e2e -m faults
"""

from __future__ import annotations

import json
import socket
import subprocess
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.base import HERE
from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import fleet, helm, pods_by_instance
from e2e.faults.record import FaultResult, record
from e2e.tests.rosbed import (
    EDGE,
    IMAGE,
    ROBOTS,
    bed_objects,
    operated_fleet,
    ros_module,
    scrape,
    scrape_series,
)
from fogfleet.render.names import (
    metrics_network_policy_name,
    network_policy_name,
    robot_network_policy_name,
    shared_network_policy_name,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's real nodes enforcing NetworkPolicy (kube-router's firewall)"),
    pytest.mark.real,
    pytest.mark.faults,
    pytest.mark.timeout(600),
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


def _objects(ns: str) -> list[dict[str, Any]]:
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


@pytest.fixture
def iso_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    with operated_fleet(kube, cluster, namespace, tmp_path, diagnostics, _objects(namespace),
                        FLEET) as ns:  # fmt: skip
        yield ns


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


def _send(
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


def _send_from_host(probes: list[tuple[str, int, str]]) -> dict[str, bool]:
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


def _pod_of(pods: dict[str, Any], robot: str, module: str) -> dict[str, Any]:
    for pod in pods.values():
        labels = pod["metadata"]["labels"]
        if labels.get("fogfleet.io/robot") == robot and labels.get("fogfleet.io/module") == module:
            return pod
    raise AssertionError(f"no {module} pod of robot {robot!r}")


def _received(pod: dict[str, Any], topic: str) -> float:
    url = f"http://{pod['status']['podIP']}:{METRICS}/metrics"
    return scrape_series(url, "fogfleet_messages_received_total", topic=topic)


def test_a_robots_pods_reach_their_own_robot_and_the_shared_services_only(
    kube: Kube, iso_fleet: str
) -> None:
    ns = iso_fleet
    t0 = time.monotonic()
    policies = kube.kubectl_json("get", "networkpolicies", "-n", ns)["items"]
    names = sorted(p["metadata"]["name"] for p in policies)
    fleet_wide = [network_policy_name(FLEET), shared_network_policy_name(FLEET),
                  metrics_network_policy_name(FLEET)]  # fmt: skip
    assert names == sorted(fleet_wide + [robot_network_policy_name(FLEET, r) for r in ROBOTS])
    status = fleet(kube, ns, FLEET)["status"]
    where = {(p.get("robot", ""), p["module"]): p["node"] for p in status["placement"]}
    for robot in ROBOTS:
        assert where[(robot, "lidar")] == robot and where[(robot, "planner")] == EDGE, where
    assert where[("", "fleet-map")] == EDGE, where
    pods = pods_by_instance(kube, ns)
    r1_lidar, r1_planner = _pod_of(pods, ROBOTS[0], "lidar"), _pod_of(pods, ROBOTS[0], "planner")
    r2_lidar, r2_planner = _pod_of(pods, ROBOTS[1], "lidar"), _pod_of(pods, ROBOTS[1], "planner")
    shared = _pod_of(pods, "", "fleet-map")

    # the planned flows work under enforcement: planners hear their robot's lidar (across the
    # link) and the shared map; the map hears the robots (Prometheus scrapes the pod IPs)
    def flowing() -> bool:
        return (
            all(_received(p, "scan") > 20 and _received(p, "map") > 3
                for p in (r1_planner, r2_planner))
            and _received(shared, "scan") > 40
        )  # fmt: skip

    kube.wait_for("messages at both planners and the shared map", flowing, 240, interval=3)
    flows_s = time.monotonic() - t0
    for planner in (r1_planner, r2_planner):
        url = f"http://{planner['status']['podIP']}:{METRICS}/metrics"
        text = scrape(url)
        assert text.get("fogfleet_foreign_messages_total", 0.0) == 0, text

    # listeners in robot-2's pods, on a port the fleet's policies do not open
    targets = {"r2planner": r2_planner, "r2lidar": r2_lidar}
    listeners = {
        key: Listener(kube, ns, p["metadata"]["name"], p["spec"]["containers"][0]["name"], 300)
        for key, p in targets.items()
    }
    senders = {"r1planner": r1_planner, "r1lidar": r1_lidar, "r2planner": r2_planner,
               "r2lidar": r2_lidar, "shared": shared}  # fmt: skip
    allowed_src = {"r2planner", "r2lidar", "shared"}
    tcp: dict[str, bool] = {}
    for src, pod in senders.items():
        probes = [(p["status"]["podIP"], PORT, f"{src}>{dst}") for dst, p in targets.items()
                  if dst != src]  # fmt: skip
        # robot-1 to robot-2's metrics port: open to Prometheus, closed by robot-1's egress
        if src.startswith("r1"):
            probes.append((r2_lidar["status"]["podIP"], METRICS, f"{src}>r2lidar:metrics"))
        tcp.update(_send(kube, ns, pod, probes))
    host = [(p["status"]["podIP"], PORT, f"host>{dst}") for dst, p in targets.items()]
    host += [(p["status"]["podIP"], METRICS, f"host>{dst}:metrics") for dst, p in targets.items()]
    tcp.update(_send_from_host(host))
    udp_heard: set[str] = set()
    tcp_heard: set[str] = set()
    for key, listener in listeners.items():
        u, t = listener.heard({tag for tag, ok in tcp.items() if ok and tag.split(">")[1] == key})
        udp_heard |= u
        tcp_heard |= t

    matrix = {}
    for tag, ok in sorted(tcp.items()):
        src = tag.split(">")[0]
        want = (tag.endswith(":metrics") and src == "host") or (
            src in allowed_src and not tag.endswith(":metrics")
        )
        udp = None if tag.endswith(":metrics") else tag in udp_heard
        matrix[tag] = {"tcp": ok, "udp": udp, "want": want}
        assert ok == want, (tag, matrix)
        if udp is not None:
            assert udp == want, (tag, matrix)
            assert (tag in tcp_heard) == want, (tag, matrix)
    print("NETPOL-MATRIX " + json.dumps(matrix, sort_keys=True))
    record(FaultResult(
        fault="a robot-1 pod sends to robot-2's pods by address (UDP, TCP)",
        messages_lost=0, cycles_missed=None, recovery_seconds=0,
        fogfleet_did="per-robot NetworkPolicies (own robot, shared services, metrics), "
                     "enforced by kube-router: every probe of robot-2 refused",
        before_fix="one fleet-wide policy: every fleet pod reached every other robot's pods",
        details={"plannedFlowsSeconds": round(flows_s, 1),
                 "denied": sorted(t for t, m in matrix.items() if not m["want"])},
    ))  # fmt: skip


# --------------------------------------------------------------------------------------------
# the shipped operator NetworkPolicy


def _shipped(source: str) -> tuple[dict[str, Any], dict[str, str], tuple[int, int]]:
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


def _standin(name: str, node: str, labels: dict[str, str], command: list[str]) -> dict[str, Any]:
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


@pytest.mark.parametrize("source", ["manifests", "chart"])
def test_the_shipped_operator_policy_admits_only_probes_and_metrics(
    kube: Kube, namespace: str, source: str
) -> None:
    policy, labels, (probe, metrics) = _shipped(source)
    policy["metadata"]["namespace"] = namespace
    kube.apply(policy, namespace)
    # the operator's stand-in (its labels, its ports) on the edge, a client on a robot
    sleep = ["python3", "-c", "import time; time.sleep(3600)"]
    kube.apply(_standin("operator", EDGE, labels, sleep), namespace)
    kube.apply(_standin("client", ROBOTS[0], {"app": "client"}, sleep), namespace)
    ip = {}
    for name in ("operator", "client"):
        kube.wait_for(f"pod {name} Running", lambda n=name: kube.kubectl_json(
            "get", "pod", n, "-n", namespace)["status"].get("phase") == "Running", 120)  # fmt: skip
        ip[name] = kube.kubectl_json("get", "pod", name, "-n", namespace)["status"]["podIP"]
    pods = {n: kube.kubectl_json("get", "pod", n, "-n", namespace) for n in ip}
    op = Listener(kube, namespace, "operator", "main", 300, (PORT, probe, metrics))
    cl = Listener(kube, namespace, "client", "main", 300)
    probes = [(ip["operator"], PORT, "client>op"), (ip["operator"], probe, "client>op:probe"),
              (ip["operator"], metrics, "client>op:metrics")]  # fmt: skip
    tcp = _send(kube, namespace, pods["client"], probes)
    tcp.update(_send(kube, namespace, pods["operator"], [(ip["client"], PORT, "op>client")]))
    tcp.update(_send_from_host([(ip["operator"], PORT, "host>op"),
                                (ip["operator"], metrics, "host>op:metrics")]))  # fmt: skip
    udp_op, tcp_op = op.heard(
        {tag for tag, ok in tcp.items() if ok and tag.split(">")[1] != "client"}
    )
    udp_cl, tcp_cl = cl.heard({tag for tag, ok in tcp.items() if ok and tag == "op>client"})
    matrix = {
        "client>op": (tcp["client>op"], "client>op" in udp_op),
        "client>op:probe": (tcp["client>op:probe"], None),
        "client>op:metrics": (tcp["client>op:metrics"], None),
        "host>op": (tcp["host>op"], "host>op" in udp_op),
        "host>op:metrics": (tcp["host>op:metrics"], None),
        "op>client (egress open)": (tcp["op>client"], "op>client" in udp_cl),
    }
    print(f"OPERATOR-NETPOL-MATRIX {source} " + json.dumps(matrix))
    # in: only the probe and metrics ports, TCP
    assert matrix["client>op:probe"][0] and matrix["client>op:metrics"][0], matrix
    assert matrix["host>op:metrics"][0], matrix
    assert matrix["client>op"] == (False, False) and matrix["host>op"] == (False, False), matrix
    assert "client>op" not in tcp_op and "host>op" not in tcp_op
    # out: open (it calls the API server, whose address differs per cluster)
    assert matrix["op>client (egress open)"] == (True, True), matrix
    assert "op>client" in tcp_cl
