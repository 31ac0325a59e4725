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
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import fleet, pods_by_instance
from e2e.faults.isolation import (
    FLEET,
    METRICS,
    PORT,
    Listener,
    iso_fleet_objects,
    pod_of,
    received,
    send,
    send_from_host,
    shipped,
    standin,
)
from e2e.faults.record import FaultResult, record
from e2e.tests.rosbed import EDGE, ROBOTS, operated_fleet, scrape
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


@pytest.fixture
def iso_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    with operated_fleet(kube, cluster, namespace, tmp_path, diagnostics,
                        iso_fleet_objects(namespace), FLEET) as ns:  # fmt: skip
        yield ns


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
    r1_lidar, r1_planner = pod_of(pods, ROBOTS[0], "lidar"), pod_of(pods, ROBOTS[0], "planner")
    r2_lidar, r2_planner = pod_of(pods, ROBOTS[1], "lidar"), pod_of(pods, ROBOTS[1], "planner")
    shared = pod_of(pods, "", "fleet-map")

    # the planned flows work under enforcement: planners hear their robot's lidar (across the
    # link) and the shared map; the map hears the robots (Prometheus scrapes the pod IPs)
    def flowing() -> bool:
        return (
            all(received(p, "scan") > 20 and received(p, "map") > 3
                for p in (r1_planner, r2_planner))
            and received(shared, "scan") > 40
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
        tcp.update(send(kube, ns, pod, probes))
    host = [(p["status"]["podIP"], PORT, f"host>{dst}") for dst, p in targets.items()]
    host += [(p["status"]["podIP"], METRICS, f"host>{dst}:metrics") for dst, p in targets.items()]
    tcp.update(send_from_host(host))
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


@pytest.mark.parametrize("source", ["manifests", "chart"])
def test_the_shipped_operator_policy_admits_only_probes_and_metrics(
    kube: Kube, namespace: str, source: str
) -> None:
    policy, labels, (probe, metrics) = shipped(source)
    policy["metadata"]["namespace"] = namespace
    kube.apply(policy, namespace)
    # the operator's stand-in (its labels, its ports) on the edge, a client on a robot
    sleep = ["python3", "-c", "import time; time.sleep(3600)"]
    kube.apply(standin("operator", EDGE, labels, sleep), namespace)
    kube.apply(standin("client", ROBOTS[0], {"app": "client"}, sleep), namespace)
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
    tcp = send(kube, namespace, pods["client"], probes)
    tcp.update(send(kube, namespace, pods["operator"], [(ip["client"], PORT, "op>client")]))
    tcp.update(send_from_host([(ip["operator"], PORT, "host>op"),
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
