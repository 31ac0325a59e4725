"""The fleet whose robot link the tests cut (test_fallback, test_faults_long_cut), and reading
what its workloads counted.

Each robot runs a camera and a safety module on board (hard real time, critical) and three
offloaded modules on the edge: the detector, with ``fallback: onboard`` (a standby on the
robot relays its outputs and takes over when they go silent), the segmenter, too heavy for
the robot, with ``fallback: variant`` (its standby runs segmenter-lite at half the rate),
and the tracker with none. The safety module consumes all three.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import fleet
from e2e.tests.rosbed import ROBOTS, bed_objects, operated_fleet, ros_module, scrape, scrape_buckets

__all__ = [
    "CYCLE_S",
    "LINK_STABLE_S",
    "LINK_WINDOW_S",
    "LITE_CYCLE_MS",
    "SILENT_CYCLES",
    "cut_fleet_objects",
    "fleet_pod",
    "gaps_since",
    "input_gaps",
    "link_of",
    "reachable",
    "running_cut_fleet",
    "since",
    "took_over",
]

CYCLE_S = 0.1  # every module's cycle but the variant's
SILENT_CYCLES = 3
LINK_WINDOW_S = 10  # spec.linkHealth.windowSeconds
LINK_STABLE_S = 30  # spec.linkHealth.stableSeconds
LITE_CYCLE_MS = 200  # the segmenter's variant


def cut_fleet_objects(ns: str, name: str) -> list[dict[str, Any]]:
    """The ComputeNodes, the modules (and segmenter-lite) and the RobotFleet ``name``."""
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
        # too heavy for the robot (no robot row): its standby runs a lighter variant
        ros_module("segmenter", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=image, publishes=[("segments", 1024, 10)],
                   profile=[("bed-edge", "50m", 10, 1)],
                   fallback={"mode": "variant", "variant": "segmenter-lite",
                             "silentCycles": SILENT_CYCLES, "stepBackCycles": 10}),
        # the control: offloaded without a fallback
        ros_module("tracker", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=image, publishes=[("tracks", 256, 10)],
                   profile=[("bed-edge", "50m", 5, 0.5)], tiers=["edge"]),
        ros_module("safety", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[("objects", 512, 10), ("tracks", 256, 10), ("segments", 1024, 10)],
                   publishes=[("stop", 64, 10)], profile=[("bed-robot", "50m", 3, 0.3)]),
    ]  # fmt: skip
    # the segmenter's variant: half the rate, a robot row; not a module of the fleet itself
    lite = ros_module("segmenter-lite", ns, cycle_ms=LITE_CYCLE_MS,
                      taxonomy=("continuous", "soft", "relevant"), subscribes=image,
                      publishes=[("segments", 1024, 5)],
                      profile=[("bed-robot", "50m", 20, 2)])  # fmt: skip
    for m in [*modules, lite]:
        m["spec"]["resources"]["memory"] = "192Mi"
    objects = [lite, *bed_objects(ns, name, modules)]
    objects[-1]["spec"]["linkHealth"] = {
        "windowSeconds": LINK_WINDOW_S,
        "stableSeconds": LINK_STABLE_S,
    }
    return objects


@contextmanager
def running_cut_fleet(
    kube: Kube,
    cluster: Cluster,
    namespace: str,
    tmp_path: Path,
    diagnostics: list[Any],
    name: str,
    extra: list[dict[str, Any]] | None = None,
) -> Iterator[str]:
    """The operator running, the fleet ``name`` (and ``extra`` objects) applied and Ready;
    robot-1's link is reset on the way out whatever happened."""
    objects = cut_fleet_objects(namespace, name) + list(extra or [])
    # the operator measures the robots' links from the bed's Prometheus (every 2 s)
    env = {"FOGFLEET_PROMETHEUS_URL": cluster.prometheus_url, "FOGFLEET_LINK_INTERVAL_SECONDS": "2"}
    try:
        with operated_fleet(
            kube, cluster, namespace, tmp_path, diagnostics, objects, name, env
        ) as ns:
            yield ns
    finally:
        cluster.reset_link(ROBOTS[0])


def fleet_pod(pods: dict[str, Any], robot: str, module: str, standby: bool = False) -> Any:
    """``robot``'s pod of ``module`` (its on-board standby with ``standby``)."""
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


def input_gaps(url: str, topic: str) -> dict[float, float]:
    """The input-gap histogram of ``topic`` at a consumer (le -> cumulative count)."""
    return scrape_buckets(url, "fogfleet_input_gap_seconds", topic=topic)


def since(after: dict[float, float], before: dict[float, float]) -> dict[float, float]:
    return {le: after[le] - before.get(le, 0.0) for le in after}


def gaps_since(url: str, topic: str, before: dict[float, float]) -> tuple[float, float]:
    """Gaps of input ``topic`` since ``before``: how many, and the smallest bucket bound (s)
    that holds them all (the longest gap is at most that)."""
    diff = since(input_gaps(url, topic), before)
    count = diff[math.inf]
    return count, min(le for le, n in diff.items() if n == count)


def took_over(
    after: dict[str, float], before: dict[str, float], remote_s: float, own_s: float, cut_s: float
) -> float:
    """A standby's takeover over a cut of ``cut_s``, from its counters: once, within the
    silence window (in the remote's cycles) plus two of its own cycles, and its own cycles
    for the whole cut. Returns its takeover gap (s)."""
    gap = after["fogfleet_fallback_takeover_gap_seconds"]
    silence = SILENT_CYCLES * remote_s
    assert silence <= gap <= silence + 2 * own_s + 0.1, gap
    took = after["fogfleet_fallback_takeovers_total"] - before["fogfleet_fallback_takeovers_total"]
    assert took == 1, took
    own = after["fogfleet_cycle_time_seconds_count"] - before["fogfleet_cycle_time_seconds_count"]
    assert own >= 0.8 * cut_s / own_s, own
    return float(gap)


def reachable(url: str) -> bool:
    try:
        scrape(url)
    except OSError:
        return False
    return True


def link_of(kube: Kube, ns: str, name: str, robot: str) -> dict[str, Any]:
    """status.links' entry of ``robot`` in fleet ``name`` ({} until measured)."""
    links = (fleet(kube, ns, name).get("status") or {}).get("links") or []
    return next((e for e in links if e["robot"] == robot), {})
