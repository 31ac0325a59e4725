"""A robot's Fast DDS discovery server dies while its fleet runs (issue 37, item 1), on real nodes.

Each robot runs a camera and a safety module on board and a detector offloaded to the edge:
``image`` flows camera -> safety on the robot and camera -> detector across the robot's link,
``objects`` flows detector -> safety back across it. Both robots use the same topic names;
only their separate discovery servers keep them apart (no module counts a message of the other
robot's: the control that discovery goes through the servers). Robot-1's discovery server then
fails three times while everything runs:

(a) its process is killed (SIGKILL by pid, found through the node's containerd): the kubelet
    restarts the container in the same pod, at the same pod IP;
(b) its pod is deleted: the Deployment makes a new pod with a new pod IP behind the same
    Service cluster IP, the address every module was given in ROS_DISCOVERY_SERVER;
(c) its process crash-loops: killed again each time the kubelet restarts it, until it has
    been down longer than a Fast DDS participant's lease (20 s), so every client has dropped
    the server as gone.

After each, the modules' own counters say what was lost on every flow, how long the longest
gap of each input was and how many cycles were missed; then a module of robot-1 is killed
(the offloaded detector after (a), the on-board safety module after (b), the camera after
(c)) and must find its peers again through the restarted server - the case Fast DDS users
report broken
(eProsima/Fast-DDS#2290, #5872: a participant created after the server restarted never
matches). Robot-2, whose server is untouched, is the control.

    flock /tmp/fogfleet-bed.lock .venv/bin/pytest e2e/tests/test_faults_discovery.py \\
        --with-e2e -m faults -s
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import conditions, fleet
from e2e.faults.discovery import (
    FLEET,
    RATE_HZ,
    REJOIN_S,
    crash_loop,
    discovery_service_ip,
    ds_fleet_objects,
    flow_losses,
    flowing,
    kill,
    kill_and_rejoin,
    metrics_url,
    missed_cycles,
    module_pods,
    ready,
    restart_count,
    server_pod,
    snapshot,
)
from e2e.faults.record import FaultResult, record
from e2e.tests.rosbed import EDGE, ROBOTS, operated_fleet

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.long,
    pytest.mark.bed("kills a real robot's discovery server process and deletes its pod"),
    pytest.mark.real,
    pytest.mark.faults,
    pytest.mark.timeout(720),
]

READY_AGAIN_S = 60  # after the last rejoin: the restarted module's readiness probe, a status pass
# after the server is Ready again the flows are watched this long before the counters are read
SETTLE_S = 15
LEASE_S = 20  # Fast DDS's default participant lease: (c) keeps the server down longer
DOWN_S = LEASE_S + 5
# Bounds, measured on the 2-core bed (three runs: 0-1 message lost per flow, gaps <= 0.3 s,
# 0-3 cycles missed of ~700, server Ready again after 7-11 s (42-43 s after the crash loop), a
# killed module talking again after 9-19 s):
SERVER_BACK_S = 30  # (a), (b): the kubelet restarts the container / a new pod, both Ready
LOST_PER_FLOW = 5  # messages; in flight at the reads (0-1 seen), the reads' skew taken out
LONGEST_GAP_S = 1.0  # the longest gap of any input over a fault (a histogram bucket bound)
MISSED_CYCLES = 20  # of robot-1's modules over a fault window
# REJOIN_S, a killed module talking again, is e2e/faults/discovery.py's: kill_and_rejoin's wait


@pytest.fixture
def ds_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    with operated_fleet(
        kube, cluster, namespace, tmp_path, diagnostics, ds_fleet_objects(namespace), FLEET
    ) as ns:
        yield ns


# --------------------------------------------------------------------------------------------


def _fault(
    kube: Kube, ns: str, name: str, inject: Any, rejoiner: str, fogfleet_did: str,
    server_back_s: float = SERVER_BACK_S,
) -> dict[str, Any]:  # fmt: skip
    """Inject one fault into robot-1's discovery server and measure it (see the docstring)."""
    robot = ROBOTS[0]
    pods = module_pods(kube, ns)
    urls = {rm: metrics_url(p) for rm, p in pods.items()}
    kube.wait_for("every module's inputs flowing", lambda: flowing(urls, ROBOTS), 120, 1)
    server = server_pod(kube, ns, robot)
    assert server is not None and ready(server)
    ip, restarts = server["status"]["podIP"], restart_count(server)
    before = snapshot(urls)
    t0 = time.monotonic()
    inject(server)

    def back() -> bool:
        pod = server_pod(kube, ns, robot)
        if pod is None or not ready(pod):
            return False
        return pod["metadata"]["uid"] != server["metadata"]["uid"] or restart_count(pod) > restarts

    kube.wait_for(f"{robot}'s discovery server back", back, server_back_s, interval=0.25)
    server_back = time.monotonic() - t0
    time.sleep(max(0.0, server_back + SETTLE_S - (time.monotonic() - t0)))
    after = snapshot(urls)
    window = time.monotonic() - t0
    new = server_pod(kube, ns, robot)
    assert new is not None
    losses = flow_losses(before, after)
    cycles, missed = missed_cycles(before, after, robot)
    foreign = sum(snap.get("foreign", 0.0) for snap in after.values())
    # every input flows after the fault (a gap is only recorded when the next message comes);
    # waited for, not read once: one 2 s window of a loaded machine may hold a stalled read
    # (generous: a silent input stays silent)
    kube.wait_for("every input flowing after the fault", lambda: flowing(urls, ROBOTS), 30, 1)
    rejoin = kill_and_rejoin(kube, ns, robot, rejoiner)
    lost = sum(f["lost"] for f in losses.values())
    longest = max(f["longestGap"] for f in losses.values())
    result = record(FaultResult(
        fault=name,
        messages_lost=lost,
        cycles_missed=missed,
        # as planned again: the server Ready (its pod or container back) and every input
        # flowing (the longest gap of any input, at most the histogram bound, is shorter)
        recovery_seconds=round(max(server_back, longest), 1),
        fogfleet_did=fogfleet_did,
        # measured first: Fast DDS 3.2.3's clients recover on their own, nothing to fix
        before_fix="the same (no fix needed)",
        details={"serverBackSeconds": round(server_back, 1), "rejoinSeconds": round(rejoin, 1),
                 "rejoined": f"{robot}/{rejoiner}", "windowSeconds": round(window, 1),
                 "cycles": cycles, "longestGapSeconds": longest, "foreignMessages": foreign,
                 "serverPodIp": [ip, new["status"]["podIP"]], "flows": losses},
    ))  # fmt: skip
    for flow, f in losses.items():
        assert f["sent"] >= 0.8 * window * RATE_HZ, (flow, f)
        assert f["lost"] <= LOST_PER_FLOW, (flow, f)
        assert f["longestGap"] <= LONGEST_GAP_S, (flow, f)
    assert server_back <= server_back_s
    assert foreign == 0, "a module got the other robot's messages: discovery leaked"
    assert missed <= MISSED_CYCLES, (cycles, missed)
    assert rejoin <= REJOIN_S
    return result.details


def test_a_killed_or_deleted_discovery_server_leaves_every_module_talking(
    kube: Kube, cluster: Cluster, ds_fleet: str
) -> None:
    ns = ds_fleet
    robot = ROBOTS[0]
    placement = fleet(kube, ns, FLEET)["status"]["placement"]
    where = {(p["robot"], p["module"]): p["node"] for p in placement}
    for r in ROBOTS:
        assert where[(r, "camera")] == r and where[(r, "safety")] == r, where
        assert where[(r, "detector")] == EDGE, where
    service_ip = discovery_service_ip(kube, ns, robot)
    pods = module_pods(kube, ns)
    for (r, _), pod in pods.items():
        env = {e["name"]: e.get("value") for e in pod["spec"]["containers"][0]["env"]}
        assert env["ROS_DISCOVERY_SERVER"] == f"{discovery_service_ip(kube, ns, r)}:11811", env
    uids = {rm: p["metadata"]["uid"] for rm, p in pods.items()}

    # (a) the server's process killed: the kubelet restarts the container, same pod and IP
    a = _fault(kube, ns, "discovery-server-process-killed", kill, "detector",
               "nothing: the kubelet restarted the container; Fast DDS clients re-announced "
               "themselves to the server at the Service address")  # fmt: skip
    assert a["serverPodIp"][0] == a["serverPodIp"][1]

    # (b) the server's pod deleted: a new pod, a new pod IP, the same Service cluster IP
    def delete(pod: Any) -> None:
        kube.kubectl("delete", "pod", "-n", ns, pod["metadata"]["name"], "--wait=false")

    b = _fault(kube, ns, "discovery-server-pod-deleted", delete, "safety",
               "nothing: the Deployment made a new pod behind the same Service cluster IP; "
               "Fast DDS clients re-announced themselves to it")  # fmt: skip
    assert b["serverPodIp"][0] != b["serverPodIp"][1], "the new server pod kept its IP"
    assert discovery_service_ip(kube, ns, robot) == service_ip

    # (c) the server crash-loops for longer than the clients' lease of it
    kills: list[int] = []
    c = _fault(kube, ns, f"discovery-server-down-{DOWN_S}s-crash-loop",
               lambda _: kills.append(crash_loop(kube, ns, robot, DOWN_S)), "camera",
               "nothing: each client dropped the server after its lease and kept its matched "
               "peers; once the kubelet ran the server again the clients re-announced "
               "themselves", server_back_s=DOWN_S + SERVER_BACK_S)  # fmt: skip
    print(f"(c): the server's process killed {kills[0]} times over {DOWN_S} s")
    assert kills[0] >= 2 and c["serverBackSeconds"] >= DOWN_S

    # no module pod was re-created or moved, and the fleet is Ready
    after = module_pods(kube, ns)
    assert {rm: p["metadata"]["uid"] for rm, p in after.items()} == uids
    # (the last module killed has just restarted: the fleet reports it, then Ready again)
    kube.wait_for(
        "the fleet Ready again",
        lambda: conditions(fleet(kube, ns, FLEET))["Ready"]["status"] == "True",
        READY_AGAIN_S,
    )
