"""`make bench-real` in miniature: one run of one arm on the ``paper`` bed, one 20 s window.

The arm is nsga2-static (nsga2's first plan, no closed loop): with the loop on, a correction
could re-plan inside a window this short, which the benchmark rightly fails.

The benchmark itself (6 nsga2 runs against 6 kube-scheduler runs, 60 s windows) is too long
for the suite; this run goes through every part of it: the bed profile (the default bed is
restarted as the paper bed, so the suite runs this test last), the fleet planned with the
run's seed, the window measured from the workload's counters in Prometheus, the placement the
cluster ran simulated beside it, and the bench-real.json document with its statistics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from e2e.bed.harness import Cluster
from e2e.bench.real import report
from e2e.bench.real.protocol import PERCEPTION, PRIMARY, Protocol
from e2e.bench.real.record import document
from e2e.bench.real.run import connect, run_bench
from e2e.bench.real.scenario import Scenario

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.long,
    pytest.mark.bed("restarts the bed with the paper profile (nodes-paper.yaml)"),
    pytest.mark.real,
    pytest.mark.paperbed,
    pytest.mark.timeout(900),
]


def test_one_run_on_the_paper_bed_is_measured_simulated_and_summarised(
    cluster: Cluster, tmp_path: Path
) -> None:
    assert cluster.profile in ("default", "paper")  # the suite's bed, restarted below
    kube, paper = connect()
    assert paper.profile == "paper"
    assert set(paper.real_nodes) == {
        "paper-robot-1",
        "paper-robot-2",
        "paper-edge-1",
        "paper-edge-2",
    }
    protocol = Protocol(window_s=20, warmup_s=10, runs={"nsga2-static": 1})
    results = run_bench(kube, paper, protocol, tmp_path)
    assert len(results) == 1
    run = results[0]
    assert run.failed is None, run.failed
    scenario = Scenario()
    doc = document(results, protocol, scenario, "e2e smoke")
    entry = doc["runs"][0]
    # every instance ran through the window and was counted; the perception pools two modules
    assert run.measured is not None
    assert set(run.measured.modules) == set(scenario.problem.module_names)
    assert all(c > 0 for c in run.measured.cycles.values()), run.measured.cycles
    pooled = entry["measured"][PRIMARY]
    assert pooled["cycles"] == sum(run.measured.cycles[m] for m in PERCEPTION)
    assert 0.0 <= pooled["missRate"] <= 1.0
    # the plan offloads the perception from the Pi robots; the taxonomy keeps the controller
    placement = entry["placement"]
    assert len(placement) == scenario.instances
    for robot in ("paper-robot-1", "paper-robot-2"):
        assert placement[f"{robot}/nav-controller"] == robot
        assert placement[f"{robot}/human-pose-estimation"].startswith("paper-edge-")
    # the simulator ran the same placement
    assert not math.isnan(entry["simulated"][PRIMARY]["missRate"])
    assert entry["seed"] == 1 and entry["scheduler"] == "nsga2-static"
    assert doc["bed"]["profile"] == "paper" and doc["bed"]["scale"] == 15
    assert doc["summary"][PRIMARY]["nsga2-static"]["runs"] == 1
    json.dumps(doc)  # the bench-real.json document serialises
    print(report.table(doc))
    # nothing is left behind: the run namespaces are gone, the ComputeNodes deleted
    left = kube.kubectl("get", "namespaces", "-l", "fogfleet.io/bench=true", "-o", "name")
    assert left.stdout.strip() == ""
    nodes = kube.kubectl("get", "computenodes", "-o", "name")
    assert "paper-edge-1" not in nodes.stdout
