"""A robot's link cut for longer than the eviction timeout (issue 37, item 5), on real nodes.

The bed shortens what a cut robot waits for before Kubernetes evicts its pods (e2e/README.md,
e2e/bed/cluster.py): kube-controller-manager marks a node whose Lease is 10 s old
(``--node-monitor-grace-period=10s``; the real kubelets renew every 2.5 s) Ready=Unknown and
taints it ``node.kubernetes.io/unreachable:NoExecute``, and kube-apiserver gives every pod
that does not say otherwise a 10 s toleration of it (``--default-unreachable-toleration-seconds``
and ``--default-not-ready-toleration-seconds``, upstream 300 s). A cut of ``CUT_SECONDS`` (60 s)
is three times grace plus toleration.

The fleet is test_fallback's (``cutfleet.py``), plus a control: a plain pause pod pinned to
robot-1 with the defaults, which must be evicted during the cut (proof that the timeout ran
out). fogfleet's pods on the robot tolerate both taints for ever (``render.ros.
ROBOT_TOLERATIONS``): none is deleted, no pod of the fleet is created anywhere (no duplicates
of the robot's modules), the standbys compute the detector's and segmenter's outputs for the
whole cut, and once the link is back no container has restarted and the fleet is as planned
again within a measured bound. What was lost comes from the workloads' own counters (read
before the cut and after it: nothing can scrape a robot that is cut off).

Measured on the 2-core machine (three runs): robot-1 tainted 9.0-10.2 s into the cut, the
control pod marked for deletion at 19.1-20.7 s; the standbys took over in 0.36-0.44 s
(detector) and 0.39-0.49 s (variant); 3 camera images got no object (the 0.3 s silence window),
none lacked a segment beyond the variant's half rate; 0-1 of ~700 safety cycles missed; the
fleet as planned again 6.8-8.0 s after the link returned; the test takes ~110 s. One run of
three saw one gap of 1-2 s in segments at the safety module (bound 1 s, as test_fallback's),
the other two none over 0.5 s: not explained yet.

    pytest e2e/tests/test_faults_long_cut.py --with-e2e -m faults
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
from e2e.bed.operator_fixtures import conditions, deployments, events, fleet
from e2e.faults.cost import metrics_url
from e2e.faults.cutfleet import (
    CYCLE_S,
    LITE_CYCLE_MS,
    fleet_pod,
    gaps_since,
    link_of,
    reachable,
    running_cut_fleet,
    took_over,
)
from e2e.faults.longcut import (
    CONTROL,
    containers,
    control_pod,
    counters,
    delta,
    fleet_pods,
    ready,
    taints,
    unanswered,
)
from e2e.faults.record import FaultResult, record
from e2e.tests.rosbed import ROBOTS, scrape, scrape_series

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.long,
    pytest.mark.bed("emulated links: cuts a real robot's link past the eviction timeout"),
    pytest.mark.real,
    pytest.mark.faults,
    pytest.mark.disconnect,
    pytest.mark.timeout(420),
]

FLEET = "longcut"
CUT_SECONDS = 60
GRACE_S = 10  # the bed's --node-monitor-grace-period (e2e/bed/cluster.py)
TOLERATION_S = 10  # the bed's --default-{unreachable,not-ready}-toleration-seconds
# the control pod is marked for deletion by then (grace + toleration + the taint manager's
# and our polling's delays: measured 19 s on the 2-core machine)
EVICTED_WITHIN_S = GRACE_S + TOLERATION_S + 15
UNREACHABLE = "node.kubernetes.io/unreachable"
NOT_READY = "node.kubernetes.io/not-ready"
RECOVERY_BOUND_S = 60  # link back -> the fleet as planned again (measured 7 s)
LOST_BOUND = 15  # messages: two takeovers' silence windows plus in-flight answers (measured 3)


@pytest.fixture
def long_cut_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    with running_cut_fleet(kube, cluster, namespace, tmp_path, diagnostics, FLEET) as ns:
        yield ns


def test_a_cut_longer_than_the_eviction_timeout_evicts_nothing_of_the_fleet(
    kube: Kube, cluster: Cluster, long_cut_fleet: str
) -> None:
    ns = long_cut_fleet
    robot, other = ROBOTS
    kube.apply(control_pod(ns, robot))
    kube.wait_for(
        "the control pod Ready on robot-1",
        lambda: ready(kube.kubectl_json("get", "pod", CONTROL, "-n", ns)),
        60,
        interval=1,
    )
    control = kube.kubectl_json("get", "pod", CONTROL, "-n", ns)
    defaults = {
        t["key"]: t.get("tolerationSeconds")
        for t in control["spec"].get("tolerations") or []
        if t.get("effect") == "NoExecute"
    }
    print(f"the control pod's NoExecute tolerations (admission's defaults): {defaults}")
    assert defaults == {UNREACHABLE: TOLERATION_S, NOT_READY: TOLERATION_S}, defaults

    pods = {
        (p["metadata"]["labels"].get("fogfleet.io/instance", ""), p["metadata"]["uid"]): p
        for p in fleet_pods(kube, ns).values()
    }
    by_instance = {i: p for (i, _), p in pods.items() if i}
    on_robot = {uid: p for (_, uid), p in pods.items() if p["spec"].get("nodeName") == robot}
    # camera, safety, two standbys and the robot's discovery server: all tolerate for ever
    print(f"fogfleet's pods on {robot}: {sorted(p['metadata']['name'] for p in on_robot.values())}")
    assert len(on_robot) == 5, sorted(p["metadata"]["name"] for p in on_robot.values())
    for p in on_robot.values():
        kept = {
            t["key"]: t.get("tolerationSeconds", "forever")
            for t in p["spec"].get("tolerations") or []
            if t.get("effect") == "NoExecute"
        }
        assert kept == {UNREACHABLE: "forever", NOT_READY: "forever"}, (p["metadata"]["name"], kept)
    before_uids = {uid for _, uid in pods}
    before_containers = {uid: containers(p) for (_, uid), p in pods.items()}
    placement = {
        (e["robot"], e["module"]): e["node"] for e in fleet(kube, ns, FLEET)["status"]["placement"]
    }
    urls = {
        "safety": metrics_url(fleet_pod(by_instance, robot, "safety")),
        "camera": metrics_url(fleet_pod(by_instance, robot, "camera")),
        "standby": metrics_url(fleet_pod(by_instance, robot, "detector", standby=True)),
        "variant": metrics_url(fleet_pod(by_instance, robot, "segmenter", standby=True)),
    }

    def flowing() -> bool:
        try:
            return all(
                scrape_series(urls["safety"], "fogfleet_messages_received_total", topic=t) > 50
                for t in ("objects", "tracks", "segments")
            ) and all(
                scrape(urls[s]).get("fogfleet_fallback_active") == 0.0
                for s in ("standby", "variant")
            )
        except OSError:
            return False

    kube.wait_for("objects, tracks and segments at robot-1's safety module", flowing, 120, 2)
    base = counters(urls)  # the steady state's unanswered images, for the baseline
    kube.wait_for(
        "both robots' links measured healthy",
        lambda: all(link_of(kube, ns, FLEET, r).get("state") == "Healthy" for r in ROBOTS),
        60,
        interval=1,
    )
    time.sleep(max(0.0, 10 - (time.monotonic() - base["t"])))
    before = counters(urls)
    other_standby = metrics_url(fleet_pod(by_instance, other, "detector", standby=True))
    other_before = scrape(other_standby)

    # ---- the cut: watch the API (the host still reaches it) until CUT_SECONDS have passed
    cut = time.monotonic()
    cluster.set_link(robot, loss_percent=100)
    tainted_at = evicted_at = None
    new_pods: dict[str, str] = {}  # uid -> "name on node"
    deleted: set[str] = set()
    reasons: set[str] = set()
    states: set[str] = set()  # status.links' state of the cut robot
    while (now := time.monotonic()) - cut < CUT_SECONDS:
        seen = fleet_pods(kube, ns)
        for uid, p in seen.items():
            if uid not in before_uids:
                new_pods[uid] = f"{p['metadata']['name']} on {p['spec'].get('nodeName')}"
            elif p["metadata"].get("deletionTimestamp"):
                deleted.add(p["metadata"]["name"])
        deleted |= {pods[k]["metadata"]["name"] for k in pods if k[1] not in seen}
        if tainted_at is None and f"{UNREACHABLE}:NoExecute" in taints(kube, robot):
            tainted_at = now - cut
        if evicted_at is None:
            ctl = kube.kubectl("get", "pod", CONTROL, "-n", ns, "-o", "json", check=False)
            if ctl.returncode != 0 or json.loads(ctl.stdout)["metadata"].get("deletionTimestamp"):
                evicted_at = now - cut
        seen_fleet = fleet(kube, ns, FLEET)
        reasons |= {
            f"{c['type']}={c['status']}/{c['reason']}"
            for c in conditions(seen_fleet).values()
            if c["type"] in ("Ready", "Degraded")
        }
        links = (seen_fleet.get("status") or {}).get("links") or []
        states |= {e.get("state", "") for e in links if e["robot"] == robot}
        time.sleep(1)
    cluster.reset_link(robot)
    back = time.monotonic()
    print(f"cut {back - cut:.0f} s; {robot} tainted {UNREACHABLE}:NoExecute after "
          f"{tainted_at or -1:.1f} s, the control pod marked for deletion after "
          f"{evicted_at or -1:.1f} s")  # fmt: skip
    print(f"the fleet's Ready/Degraded conditions seen during the cut: {sorted(reasons)}; "
          f"{robot}'s link: {sorted(states)}")  # fmt: skip
    assert "Lost" in states and "Degraded=True/NodeUnavailable" in reasons, (states, reasons)
    assert tainted_at is not None and tainted_at <= GRACE_S + 10, tainted_at
    assert evicted_at is not None and evicted_at <= EVICTED_WITHIN_S, evicted_at
    assert CUT_SECONDS - evicted_at >= 20, "the cut outlasted the eviction by too little"
    assert not deleted, f"fogfleet's pods deleted during the cut: {sorted(deleted)}"
    assert not new_pods, f"pods created during the cut: {new_pods}"

    # ---- the link is back: the fleet as planned again, the standbys handing back
    def as_planned() -> bool:
        now_pods = fleet_pods(kube, ns)
        deps = deployments(kube, ns)
        conds = conditions(fleet(kube, ns, FLEET))
        return (
            set(now_pods) == before_uids
            and all(ready(p) for p in now_pods.values())
            and all(
                (d.get("status") or {}).get("availableReplicas", 0) == d["spec"]["replicas"]
                for d in deps
            )
            and conds["Ready"]["status"] == "True"
            and conds["Degraded"]["status"] == "False"
            and link_of(kube, ns, FLEET, robot).get("state") == "Healthy"
        )

    kube.wait_for("robot-1's pods reachable again", lambda: reachable(urls["standby"]), 60)
    kube.wait_for("the fleet as planned again", as_planned, RECOVERY_BOUND_S, interval=1)
    recovery = time.monotonic() - back
    print(f"the fleet as planned again {recovery:.1f} s after the link returned")
    kube.wait_for(
        "the standbys handing back to the remote instances",
        lambda: all(
            scrape(urls[s]).get("fogfleet_fallback_active") == 0.0 for s in ("standby", "variant")
        ),
        60,
        interval=1,
    )
    # a gap is recorded when the next message arrives: wait for tracks to flow again
    tracks_then = scrape_series(urls["safety"], "fogfleet_messages_received_total", topic="tracks")
    kube.wait_for(
        "tracks at robot-1's safety module again",
        lambda: (
            scrape_series(urls["safety"], "fogfleet_messages_received_total", topic="tracks")
            > tracks_then + 10
        ),
        60,
        interval=1,
    )
    after = counters(urls)
    # the kubelet, back in touch, finished the control pod's eviction
    kube.wait_for(
        "the evicted control pod gone",
        lambda: kube.kubectl("get", "pod", CONTROL, "-n", ns, check=False).returncode != 0,
        60,
        interval=1,
    )

    # nothing restarted: same pods, same containers, no restarts; counters only grew
    now_pods = fleet_pods(kube, ns)
    assert set(now_pods) == before_uids
    changed = {
        now_pods[uid]["metadata"]["name"]: (before_containers[uid], containers(now_pods[uid]))
        for uid in before_uids
        if containers(now_pods[uid]) != before_containers[uid]
    }
    assert not changed, f"containers restarted or replaced: {changed}"
    for who in ("camera", "safety", "standby", "variant"):
        assert delta(before, after, who, "fogfleet_cycle_time_seconds_count") > 0, who
    assert {
        (e["robot"], e["module"]): e["node"] for e in fleet(kube, ns, FLEET)["status"]["placement"]
    } == placement
    assert fleet(kube, ns, FLEET)["status"]["migrations"] == 0

    # the fallbacks ran throughout: each took over once, within its silence window, and
    # computed its own cycles for the whole cut (test_fallback's figures)
    gap = took_over(after["standby"], before["standby"], CYCLE_S, CYCLE_S, CUT_SECONDS)
    lite_s = LITE_CYCLE_MS / 1e3
    vgap = took_over(after["variant"], before["variant"], CYCLE_S, lite_s, CUT_SECONDS)
    print(f"takeovers: detector standby {gap:.3f} s, segmenter variant {vgap:.3f} s")
    gaps, longest = gaps_since(urls["safety"], "objects", before["objects_gaps"])
    sgaps, slongest = gaps_since(urls["safety"], "segments", before["segments_gaps"])
    print(f"at robot-1's safety module: objects' longest gap <= {longest} s, "
          f"segments' <= {slongest} s")  # fmt: skip
    assert longest <= 0.6 and slongest <= 1.0
    # and they kept arriving all through the cut (the variant at its half rate)
    assert gaps >= 0.8 * CUT_SECONDS / CYCLE_S and sgaps >= 0.8 * CUT_SECONDS * 1e3 / LITE_CYCLE_MS
    assert after["out_of_order"] - before["out_of_order"] == 0  # no input answered twice
    # messages lost: unanswered images beyond the steady state's (in-flight answers)
    base_images, base_objects, base_segments = unanswered(base, before)
    images, no_object, no_segment = unanswered(before, after)
    tracks_lost = images - (after["tracks"] - before["tracks"])
    print(f"tracks (no fallback) lost over the cut: {tracks_lost:.0f} of {images:.0f}")
    assert tracks_lost >= 0.8 * CUT_SECONDS / CYCLE_S  # the control of the figures
    # the steady state answers every image (but the one or two in flight at a reading)
    assert abs(base_objects) <= 2 and abs(base_segments) <= 2, (base_objects, base_segments)
    lost_objects, lost_segments = max(0.0, no_object), max(0.0, no_segment)
    print(
        f"steady state over {before['t'] - base['t']:.0f} s: {base_images:.0f} images, "
        f"{base_objects:.0f} without an object, {base_segments:.0f} without a segment"
    )
    print(f"over the cut ({after['t'] - before['t']:.0f} s): {images:.0f} images, "
          f"{no_object:.0f} without an object, {no_segment:.0f} without a segment")  # fmt: skip
    lost = lost_objects + lost_segments
    assert lost <= LOST_BOUND, (lost_objects, lost_segments)
    # cycles: the safety module and the camera (both hard real time, on board) kept theirs
    elapsed = after["t"] - before["t"]
    missed = 0.0
    for who in ("camera", "safety"):
        ran = delta(before, after, who, "fogfleet_cycle_time_seconds_count")
        late = delta(before, after, who, "fogfleet_missed_cycles_total")
        print(f"{who} over {elapsed:.0f} s: {ran:.0f} cycles, {late:.0f} missed")
        assert ran >= 0.9 * elapsed / CYCLE_S and late <= 0.01 * ran, who
        missed += late
    # the other robot never noticed; the Events said what happened
    other_after = scrape(other_standby)
    took = (other_after["fogfleet_fallback_takeovers_total"]
            - other_before["fogfleet_fallback_takeovers_total"])  # fmt: skip
    assert took == 0 and other_after["fogfleet_fallback_active"] == 0.0, took
    said = {e["reason"] for e in events(kube, ns, name=FLEET)}
    assert {"LinkLost", "LinkHealthy"} <= said, said
    record(FaultResult(
        fault=f"robot link cut {back - cut:.0f} s, past eviction ({GRACE_S} s grace + "
        f"{TOLERATION_S} s toleration; a control pod evicted at {evicted_at:.0f} s)",
        messages_lost=round(lost),
        cycles_missed=round(missed),
        recovery_seconds=round(recovery, 1),
        fogfleet_did="kept its 5 pods on the robot (NoExecute tolerations without "
        "tolerationSeconds), created no pod elsewhere, standbys computed through the cut, "
        "reported Lost/NodeUnavailable and moved nothing; no container restarted after",
        before_fix="nothing to fix: robot-pinned pods already tolerated the taints for ever "
        "(issue 13)",
        details={"objectsLost": round(lost_objects), "segmentsLost": round(lost_segments),
                 "tracksLostWithoutFallback": round(tracks_lost)},
    ))  # fmt: skip
