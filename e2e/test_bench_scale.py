"""`make bench-scale` in miniature: 5 robots x 8 modules through the same code as the 100-1000
robot runs - plain Deployments, a fresh operator, the Ready lag, a robot joining - and the
bench-scale.json document. What is asserted holds at any size: every pod ran both ways, the
fleet became Ready only once its pods ran, the joining robot's modules were planned in a new
plan, and what the operator moved on the join is bounded by what it had placed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from e2e import bench_scale
from e2e.cluster import heartbeats
from e2e.cluster.controlplane import Heartbeats
from e2e.cluster.kube import Kube

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]


def test_a_small_fleet_goes_through_every_step_of_the_scale_benchmark(
    kube: Kube, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench-scale.json"
    assert bench_scale.main(["--sizes", "5", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    (row,) = doc["sizes"]
    assert (row["robots"], row["pods"], row["edges"]) == (5, 40, 2)
    assert "error" not in row
    assert 0 < row["plainApplySeconds"] < row["plainSeconds"]
    assert row["plainDiscoveryServers"] == 5  # the plain fleet runs the operator's pods too
    assert row["plainSeconds"] > 0 and row["operatorSeconds"] > row["planningSeconds"] > 0
    assert row["firstPlanSeconds"] == row["planningSeconds"]
    # Ready is seen after the last pod runs (a fleet Ready before its pods would be a lie)
    assert -1 < row["readyLagSeconds"] < 30  # two watchers of the same pods: ms apart
    assert row["incrementalReplanSeconds"] > 0 and row["joinToReadySeconds"] > 0
    assert 0 <= row["incrementalMoved"] <= row["pods"]
    # measured with a large cluster's heartbeats, and the bed's are back afterwards
    assert (doc["nodeLeaseSeconds"], doc["nodeMonitorGracePeriod"]) == (120, "120s")
    assert doc["rssSlopes"] == []  # one size: no interval
    assert heartbeats.current() == Heartbeats()
    assert row["operatorPeakRssMiB"] > 50
    table = capsys.readouterr().out
    assert "Ready lag s" in table and "\n5 " in table
    left = kube.kubectl("get", "namespaces", "-l", "fogfleet.io/bench=true", "-o", "name")
    assert left.stdout.strip() == ""
    nodes = kube.kubectl("get", "nodes", "-l", "fogfleet.io/bench=true", "-o", "name")
    assert nodes.stdout.strip() == ""


def test_the_rss_slope_is_per_interval_so_superlinear_growth_shows() -> None:
    rows = [
        {"robots": 100, "pods": 800, "operatorPeakRssMiB": 300.0},
        {"robots": 5, "pods": 40, "error": "failed"},
        {"robots": 300, "pods": 2400, "operatorPeakRssMiB": 700.0},
        {"robots": 1000, "pods": 8000, "operatorPeakRssMiB": 3500.0},
    ]
    assert bench_scale.rss_slopes(rows) == [
        {"fromPods": 800, "toPods": 2400, "peakMiBPer1000Pods": 250.0},
        {"fromPods": 2400, "toPods": 8000, "peakMiBPer1000Pods": 500.0},
    ]
    assert bench_scale.rss_slopes(rows[:2]) == []
