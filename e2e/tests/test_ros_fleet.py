"""A real ROS 2 fleet on real nodes: two robots whose modules are split between the robots and
the edge node, wired by the operator (a discovery server per robot), measured by Prometheus.

Everything here is real: rclpy processes in containers under the nodes' CPU quotas, Fast DDS
unicast discovery through ClusterIP Services (kube-proxy), messages over the emulated links,
the workload's own counters scraped by Prometheus.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import fleet, pods_by_instance
from e2e.tests.rosbed import (
    EDGE,
    PROBE_PORT,
    ROBOTS,
    operated_fleet,
    scrape,
    split_fleet,
)
from fogfleet.contract.env import METRICS_PORT

WINDOW_CYCLES = 5  # planner cycles (1 s each) its own mean and the probe's are compared over

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus scraping pod IPs; test_portable.py checks messages"),
    pytest.mark.real,
    pytest.mark.timeout(600),
]


@pytest.fixture
def ros_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    objects = split_fleet(namespace)
    with operated_fleet(kube, cluster, namespace, tmp_path, diagnostics, objects, "bedfleet") as ns:
        yield ns


def _series(cluster: Cluster, promql: str) -> dict[tuple[str, str], float]:
    out = {}
    for r in cluster.prometheus_query(promql):
        m = r["metric"]
        out[(m.get("module", ""), m.get("robot", ""))] = float(r["value"][1])
    return out


def test_a_split_ros_fleet_talks_across_nodes_within_each_robot_only(
    kube: Kube, cluster: Cluster, ros_fleet: str
) -> None:
    ns = ros_fleet
    status = fleet(kube, ns, "bedfleet")["status"]
    where = {(p["robot"], p["module"]): p["node"] for p in status["placement"]}
    for robot in ROBOTS:
        assert where[(robot, "lidar")] == robot and where[(robot, "localizer")] == robot
        assert where[(robot, "planner")] == EDGE
    pods = pods_by_instance(kube, ns)
    assert len(pods) == 6 and all(p["status"]["podIP"].startswith("198.18.") for p in pods.values())
    sel = f'namespace="{ns}"'
    kube.wait_for(
        "every module's cycles in Prometheus",
        lambda: len(_series(cluster, f"fogfleet_cycle_time_seconds_count{{{sel}}} > 5")) == 6,
        180,
        interval=3,
    )
    # the offloaded planners hear their own robot's localizer, across the emulated links
    received = _series(
        cluster, f"sum by (module, robot) (fogfleet_messages_received_total{{{sel}}})"
    )
    for robot in ROBOTS:
        assert received.get(("planner", robot), 0) > 10, received
        assert received.get(("localizer", robot), 0) > 10, received
    # and never the other robot's (the workload's own leak counter)
    leaks = _series(cluster, f"sum by (module, robot) (fogfleet_foreign_messages_total{{{sel}}})")
    assert sum(leaks.values()) == 0, f"cross-robot messages: {leaks}"
    # measured cycle times are what the profiles predict: the workload plays a row at its pace
    # (cpu cores for mean seconds, workload.burn), so an instance with room on its node takes
    # about the row's mean; at most half as long again plus the link, never the cycle time
    mean = _series(
        cluster,
        f"sum by (module, robot) (fogfleet_cycle_time_seconds_sum{{{sel}}})"
        f" / sum by (module, robot) (fogfleet_cycle_time_seconds_count{{{sel}}})",
    )
    profile = {"lidar": (0.004, 0.1), "localizer": (0.015, 0.1), "planner": (0.120, 1.0)}
    report = {f"{m}/{r}": f"{v * 1e3:.1f} ms" for (m, r), v in sorted(mean.items())}
    print(f"measured mean cycle times: {report}")
    assert len(mean) == 6, report
    for (module, robot), value in mean.items():
        exec_s, cycle_s = profile[module]
        assert 0.8 * exec_s <= value <= min(1.5 * exec_s + 0.02, cycle_s), f"{module}/{robot}"
    missed = _series(cluster, f"sum by (module, robot) (fogfleet_missed_cycles_total{{{sel}}})")
    print(f"missed cycles: {missed}")

    # the cycle-time probe beside each planner measures it from the messages alone: the
    # planner's cycle plus the wait of its freshest pose for the next 1 s tick (poses come
    # every 100 ms, so at most ~0.1 s more), and every one of its outputs is timed
    for robot in ROBOTS:
        pod = next(
            p
            for p in pods.values()
            if p["metadata"]["labels"].get("fogfleet.io/robot") == robot
            and p["metadata"]["labels"].get("fogfleet.io/module") == "planner"
        )
        url = f"http://{pod['status']['podIP']}:{PROBE_PORT}/metrics"
        own_url = f"http://{pod['status']['podIP']}:{METRICS_PORT}/metrics"
        # the probe counts a cycle once it has discovered both topics across the link, which
        # can come a few planner cycles after the planner's own first ones: wait for three
        kube.wait_for(f"three cycles timed by {robot}'s probe", partial(_timed, url, 3), 60, 2)
        # then both over the same cycles: the planner's first ones, under the rollout's load,
        # are slower than the later ones the probe times (133 against 127 ms once)
        own0, probed0 = scrape(own_url), scrape(url)
        timed = probed0["fogfleet_cycle_time_seconds_count"] + WINDOW_CYCLES
        kube.wait_for(
            f"{WINDOW_CYCLES} more timed by {robot}'s probe", partial(_timed, url, timed), 60, 2
        )
        own1, probed = scrape(own_url), scrape(url)
        own, probe_mean = _mean_between(own0, own1), _mean_between(probed0, probed)
        print(f"planner/{robot}: own {own * 1e3:.1f} ms, probe {probe_mean * 1e3:.1f} ms")
        assert own - 0.005 <= probe_mean <= own + 0.1 + 0.05, (own, probe_mean)
        assert probed.get("fogfleet_foreign_messages_total", 0.0) == 0, probed


def _mean_between(before: dict[str, float], after: dict[str, float]) -> float:
    """The mean cycle time of the cycles counted between two scrapes of one endpoint."""
    name = "fogfleet_cycle_time_seconds"
    cycles = after[f"{name}_count"] - before[f"{name}_count"]
    return (after[f"{name}_sum"] - before[f"{name}_sum"]) / cycles


def _timed(url: str, cycles: int) -> bool:
    return scrape(url).get("fogfleet_cycle_time_seconds_count", 0.0) >= cycles
