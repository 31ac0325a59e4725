"""A robot's link cut for 60 s while its perception runs on the edge (issue 13), on real nodes.

Each robot runs a camera and a safety module on board (hard real time, critical) and two
offloaded modules on the edge: the detector, with ``fallback: onboard`` (a standby on the
robot relays its outputs and takes over when they go silent), and the tracker with none. The
safety module consumes both. Cutting robot-1's emulated link (100 % loss both ways: its
kubelet loses the API server too) must leave its objects flowing - the standby takes over
within the silence window plus two cycles, with no input answered twice on the robot - while
its tracks stop for the whole cut; after the link returns the remote detector serves again.

Nothing can scrape a robot cut off from the host, so every figure comes from the counters
and histograms the workloads keep (read before the cut and after it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.cluster.harness import Cluster
from e2e.cluster.kube import Kube
from e2e.operator_fixtures import fleet, pods_by_instance
from e2e.rosbed import (
    EDGE,
    ROBOTS,
    bed_objects,
    operated_fleet,
    ros_module,
    scrape,
    scrape_buckets,
    scrape_series,
)

pytestmark = [pytest.mark.e2e, pytest.mark.real, pytest.mark.disconnect, pytest.mark.timeout(600)]

CUT_SECONDS = 60
CYCLE_S = 0.1
SILENT_CYCLES = 3
FLEET = "cutfleet"


def _objects(ns: str) -> list[dict[str, Any]]:
    image = [("image", 8192, 10)]
    modules = [
        ros_module("camera", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[], publishes=image, profile=[("bed-robot", "50m", 3, 0.3)]),
        # the edge is preferred, and with a fallback the robot keeps its share for the standby
        ros_module("detector", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=image, publishes=[("objects", 512, 10)],
                   profile=[("bed-robot", "100m", 30, 3), ("bed-edge", "100m", 15, 1.5)],
                   preferredTiers=["edge"],
                   fallback={"mode": "onboard", "silentCycles": SILENT_CYCLES,
                             "stepBackCycles": 10}),
        # the control: offloaded without a fallback
        ros_module("tracker", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=image, publishes=[("tracks", 256, 10)],
                   profile=[("bed-edge", "50m", 5, 0.5)], tiers=["edge"]),
        ros_module("safety", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[("objects", 512, 10), ("tracks", 256, 10)],
                   publishes=[("stop", 64, 10)], profile=[("bed-robot", "50m", 3, 0.3)]),
    ]  # fmt: skip
    for m in modules:
        m["spec"]["resources"]["memory"] = "192Mi"
    return bed_objects(ns, FLEET, modules)


@pytest.fixture
def cut_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    objects = _objects(namespace)
    try:
        with operated_fleet(kube, cluster, namespace, tmp_path, diagnostics, objects, FLEET) as ns:
            yield ns
    finally:
        cluster.reset_link(ROBOTS[0])


def _pod(pods: dict[str, Any], robot: str, module: str, standby: bool = False) -> Any:
    for pod in pods.values():
        labels = pod["metadata"]["labels"]
        is_standby = labels.get("app.kubernetes.io/component") == "fallback-standby"
        if (
            labels.get("fogfleet.io/robot") == robot
            and labels.get("fogfleet.io/module") == module
            and is_standby == standby
        ):
            return pod
    raise AssertionError(f"no {'standby ' if standby else ''}{module} pod of {robot}")


def _url(pod: Any) -> str:
    return f"http://{pod['status']['podIP']}:9100/metrics"


def _gaps(url: str, topic: str) -> dict[float, float]:
    """The input-gap histogram of ``topic`` at the safety module (le -> cumulative count)."""
    return scrape_buckets(url, "fogfleet_input_gap_seconds", topic=topic)


def _since(after: dict[float, float], before: dict[float, float]) -> dict[float, float]:
    return {le: after[le] - before.get(le, 0.0) for le in after}


def _reachable(url: str) -> bool:
    try:
        scrape(url)
    except OSError:
        return False
    return True


def test_a_cut_link_leaves_the_fallbacks_outputs_flowing_and_stops_the_others(
    kube: Kube, cluster: Cluster, cut_fleet: str
) -> None:
    ns = cut_fleet
    robot, other = ROBOTS
    status = fleet(kube, ns, FLEET)["status"]
    where = {(p["robot"], p["module"]): p["node"] for p in status["placement"]}
    for r in ROBOTS:
        assert where[(r, "detector")] == EDGE and where[(r, "tracker")] == EDGE, where
        assert where[(r, "camera")] == r and where[(r, "safety")] == r, where
    # what a cut costs each robot, as the operator predicts it
    cuts = {c["robot"]: c for c in status["fallbacks"]}
    print(f"status.fallbacks: {status['fallbacks']}")
    for r in ROBOTS:
        assert cuts[r]["standbys"] == ["detector"] and cuts[r]["stopped"] == ["tracker"]
        assert cuts[r]["reservedCpu"] == "100m"  # the detector's on-board row
    pods = pods_by_instance(kube, ns)
    standby = {r: _pod(pods, r, "detector", standby=True) for r in ROBOTS}
    for r in ROBOTS:
        assert standby[r]["spec"]["nodeName"] == r  # the standby runs on its robot
    safety_url, standby_url = _url(_pod(pods, robot, "safety")), _url(standby[robot])
    # both inputs flow and the standby only relays (the remote detector serves)
    kube.wait_for(
        "objects and tracks at the safety module, the standby idle",
        lambda: (
            scrape_series(safety_url, "fogfleet_messages_received_total", topic="objects") > 50
            and scrape_series(safety_url, "fogfleet_messages_received_total", topic="tracks") > 50
            and scrape(standby_url).get("fogfleet_fallback_active") == 0.0
        ),
        120,
        interval=2,
    )
    before: dict[str, Any] = {
        "safety": scrape(safety_url),
        "standby": scrape(standby_url),
        "objects": _gaps(safety_url, "objects"),
        "tracks": _gaps(safety_url, "tracks"),
        "out_of_order": scrape_series(
            safety_url, "fogfleet_out_of_order_messages_total", topic="objects"
        ),
    }
    cut = time.monotonic()
    cluster.set_link(robot, loss_percent=100)
    time.sleep(CUT_SECONDS)
    cluster.reset_link(robot)
    back = time.monotonic()
    kube.wait_for("robot-1's pods reachable again", lambda: _reachable(standby_url), 60)
    kube.wait_for(
        "the standby hands back to the remote detector",
        lambda: scrape(standby_url).get("fogfleet_fallback_active") == 0.0,
        90,
        interval=1,
    )
    print(f"cut {back - cut:.0f} s; handed back {time.monotonic() - back:.1f} s later")
    # a gap is recorded when the next message arrives: wait for tracks to flow again
    tracks_then = scrape_series(safety_url, "fogfleet_messages_received_total", topic="tracks")
    kube.wait_for(
        "tracks at robot-1's safety module again",
        lambda: (
            scrape_series(safety_url, "fogfleet_messages_received_total", topic="tracks")
            > tracks_then + 10
        ),
        60,
        interval=1,
    )
    print(f"tracks again {time.monotonic() - back:.1f} s after the link returned")
    safety, sb = scrape(safety_url), scrape(standby_url)

    # the standby took over once, within the silence window and two cycles of the remote's
    # last output (its own measure), and computed the objects for the whole cut
    gap = sb["fogfleet_fallback_takeover_gap_seconds"]
    print(f"takeover: {gap:.3f} s from the remote's last output to the standby's first")
    assert SILENT_CYCLES * CYCLE_S <= gap <= SILENT_CYCLES * CYCLE_S + 2 * CYCLE_S + 0.1
    assert (
        sb["fogfleet_fallback_takeovers_total"]
        == before["standby"]["fogfleet_fallback_takeovers_total"] + 1
    )
    own_cycles = (
        sb["fogfleet_cycle_time_seconds_count"]
        - before["standby"]["fogfleet_cycle_time_seconds_count"]
    )
    assert own_cycles >= 0.8 * CUT_SECONDS / CYCLE_S, own_cycles
    # at the safety module: no gap in objects longer than the takeover (silence window plus
    # two cycles; the histogram's bucket above it is 0.6 s), tracks gone for the whole cut
    objects = _since(_gaps(safety_url, "objects"), before["objects"])
    gaps = objects[math.inf]
    longest = min(le for le, n in objects.items() if n == gaps)
    print(f"objects at robot-1's safety module over the cut: {gaps:.0f} gaps, all <= {longest} s")
    assert gaps >= 0.8 * CUT_SECONDS / CYCLE_S and longest <= 0.6, objects
    tracks = _since(_gaps(safety_url, "tracks"), before["tracks"])
    print(f"tracks at robot-1's safety module over the cut (gaps up to le s): {tracks}")
    assert tracks[math.inf] - tracks[30.0] == 1, "the tracker (no fallback) left no >30 s gap"
    # and no input answered twice
    out_of_order = (
        scrape_series(safety_url, "fogfleet_out_of_order_messages_total", topic="objects")
        - before["out_of_order"]
    )
    assert out_of_order == 0
    # the safety module kept its cycles through the cut
    cycles = (
        safety["fogfleet_cycle_time_seconds_count"]
        - before["safety"]["fogfleet_cycle_time_seconds_count"]
    )
    missed = safety.get("fogfleet_missed_cycles_total", 0.0) - before["safety"].get(
        "fogfleet_missed_cycles_total", 0.0
    )
    print(f"safety module over the cut: {cycles:.0f} cycles, {missed:.0f} missed")
    assert cycles >= 0.9 * (back - cut) / CYCLE_S and missed <= 0.01 * cycles
    # the other robot never noticed
    other_sb = scrape(_url(standby[other]))
    assert other_sb.get("fogfleet_fallback_active") == 0.0
    # nothing was restarted or moved by the cut (the operator kept the cut robot's standby)
    after = pods_by_instance(kube, ns)
    assert {n: p["metadata"]["uid"] for n, p in after.items()} == {
        n: p["metadata"]["uid"] for n, p in pods.items()
    }
