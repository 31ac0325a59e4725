"""`make bench-scale` in miniature: 5 robots x 8 modules through the same code as the 100-1000
robot runs - plain Deployments, a fresh operator, the Ready lag, a robot joining - and the
bench-scale.json document. What is asserted holds at any size: every pod ran both ways, the
fleet became Ready only once its pods ran, the joining robot's modules were planned in a new
plan, and what the operator moved on the join is bounded by what it had placed, and each path's
CPU seconds add up within the machine's. One run: the medians over repeats are
``median_row``'s, tested below without a cluster (two runs here cost CI ~2.5 minutes)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from e2e.bed import heartbeats
from e2e.bed.controlplane import Heartbeats
from e2e.bed.cpu_meter import CONTROL_PLANE
from e2e.bed.kube import Kube
from e2e.bench import scale as bench_scale
from fogfleet.bench.record import read_record

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("replaces the bed's kwok nodes (hundreds of fake robots)"),
    pytest.mark.timeout(600),
]


@pytest.mark.long
def test_a_small_fleet_goes_through_every_step_of_the_scale_benchmark(
    kube: Kube, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench-scale.json"
    assert bench_scale.main(["--sizes", "5", "--repeats", "1", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    (row,) = doc["sizes"]
    assert (row["robots"], row["pods"], row["edges"]) == (5, 40, 2)
    assert "error" not in row
    assert row["repeats"] == 1 and len(row["runs"]) == 1
    assert all("error" not in r for r in row["runs"])
    for path, parts in (("plain", {"benchmark"}), ("operator", {"benchmark", "fogfleet"})):
        cpu = row[f"{path}CpuSeconds"]
        assert set(cpu) == {"machine", *CONTROL_PLANE, *parts}
        assert cpu["kube-apiserver"] > 0 and cpu["kube-scheduler"] > 0
        # the parts are processes on the machine: together no more than its busy time
        assert sum(v for k, v in cpu.items() if k != "machine") <= cpu["machine"] + 0.5
    assert 0 < row["plainApplySeconds"] < row["plainSeconds"]
    assert row["plainDiscoveryServers"] == 5  # the plain fleet runs the operator's pods too
    assert row["plainSeconds"] > 0 and row["operatorSeconds"] > row["planningSeconds"] > 0
    assert row["firstPlanSeconds"] == row["planningSeconds"]
    # Ready is seen after the last pod runs (a fleet Ready before its pods would be a lie)
    assert -1 < row["readyLagSeconds"] < 30  # two watchers of the same pods: ms apart
    assert row["incrementalReplanSeconds"] > 0 and row["joinToReadySeconds"] > 0
    assert 0 <= row["incrementalMoved"] <= row["pods"]
    # the second robot joins once the control plane is quiet, well before the wait's cap
    assert 0 < row["settleWaitSeconds"] < bench_scale.QUIET_MAX_SECONDS
    assert row["settledIncrementalReplanSeconds"] > 0 and row["settledJoinToReadySeconds"] > 0
    assert 0 <= row["settledIncrementalMoved"] <= row["pods"]
    # measured with a large cluster's heartbeats, and the bed's are back afterwards
    assert (doc["nodeLeaseSeconds"], doc["nodeMonitorGracePeriod"]) == (120, "120s")
    # a benchmark record: the benchmarks page renders its table (make bench-plan-page)
    record = read_record(out)
    assert record["suite"] == "scale" and record["result"] == bench_scale.page_rows([row])
    assert doc["rssSlopes"] == []  # one size: no interval
    assert heartbeats.current() == Heartbeats()
    assert row["operatorPeakRssMiB"] > 50
    table = capsys.readouterr().out
    assert "Ready lag s" in table and "\n5 " in table
    assert "by part of the bed" in table and "kube-apiserver" in table
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


def test_repeated_runs_give_each_number_as_a_median_and_keep_the_runs() -> None:
    runs = [
        {"robots": 100, "pods": 800, "ratio": 1.3, "incrementalMoved": 2,
         "plainCpuSeconds": {"machine": 80.0, "kwok": 5.0}},
        {"robots": 100, "pods": 800, "ratio": 0.9, "incrementalMoved": 0,
         "plainCpuSeconds": {"machine": 60.0, "kwok": 7.0}},
        {"robots": 100, "pods": 800, "error": "timeout"},
        {"robots": 100, "pods": 800, "ratio": 1.0, "incrementalMoved": 1,
         "plainCpuSeconds": {"machine": 70.0, "kwok": 6.0}},
    ]  # fmt: skip
    row = bench_scale.median_row(runs)
    assert (row["robots"], row["ratio"], row["incrementalMoved"]) == (100, 1.0, 1)
    assert isinstance(row["robots"], int) and isinstance(row["pods"], int)
    assert row["plainCpuSeconds"] == {"machine": 70.0, "kwok": 6.0}
    assert row["runs"] == runs and row["repeats"] == 4
    assert row["error"] == "1 of 4 runs failed: timeout"
    failed = bench_scale.median_row(runs[2:3])
    assert failed["error"] == "timeout" and failed["repeats"] == 1


def test_the_page_table_has_a_column_per_figure_and_the_runs_each_median_is_over() -> None:
    rows = [
        {"robots": 1000, "pods": 8000, "plainSeconds": 600.0, "operatorSeconds": 480.25,
         "wholeRatio": 0.8004, "firstPlanSeconds": 9.5, "ratio": 0.784, "incrementalMoved": 3,
         "repeats": 3},
        {"robots": 5, "pods": 40, "error": "timeout", "repeats": 1},
    ]  # fmt: skip
    first, failed = bench_scale.page_rows(rows)
    assert (first["plain s"], first["operator s"], first["first plan s"]) == (
        "600.0",
        "480.2",
        "9.5",
    )
    assert (first["operator/plain"], first["(op-plan)/plain"]) == ("0.80", "0.78")
    assert (first["moved"], first["runs"]) == ("3", "3")
    assert first["settled join->Ready s"] == "-" and failed["plain s"] == "-"
    assert list(first) == list(failed)  # one header: the settled join's columns are apart
