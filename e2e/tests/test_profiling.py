"""A module with no profile for the robots' hardware is profiled by real Jobs, then placed
(issue 10, item 3), on the bed's real nodes.

The mapper declares one row, measured on the edge, and ``profiling: {mode: auto}`` over four
CPU limits; its container's real work is 10 ms of CPU a cycle (``module --cpu-work 10``). The
fleet waits (``ProfilingPending``) while the operator runs three profiling Jobs of the
mapper's own image on the robots' hardware type (the grid's smallest, middle and largest
limit), reads what each measured from its termination message, fits the fourth limit, writes
the profile to the module's status and plans the fleet with it. Every number comes from the
Jobs' own measurement under the real CFS quota of their CPU limit.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    conditions,
    events,
    fleet,
    profiling_of,
    wait_profiling_jobs_deleted,
)
from e2e.tests.rosbed import ROBOTS, bed_objects, operated_fleet, ros_module

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus scraping pod IPs from the host"),
    pytest.mark.real,
    pytest.mark.closedloop,
    pytest.mark.timeout(600),
]

FLEET = "profiledfleet"
MODULE = "mapper"
WORK_MS = 10
GRID = ["50m", "100m", "150m", "200m"]


def _objects(ns: str) -> list[dict[str, Any]]:
    mapper = ros_module(
        MODULE,
        ns,
        cycle_ms=200,
        taxonomy=("continuous", "soft", "relevant"),
        subscribes=[],
        publishes=[("map", 1024, 5)],
        profile=[("bed-edge", "100m", 12, 1)],
        profiling={"mode": "auto", "cpus": GRID, "cycles": 20, "timeoutSeconds": 180},
    )
    mapper["spec"]["resources"]["memory"] = "192Mi"
    mapper["spec"]["template"]["args"] = ["module", "--cpu-work", str(WORK_MS)]
    return bed_objects(ns, FLEET, [mapper])


@pytest.fixture
def profiled_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[tuple[str, float]]:
    start = time.monotonic()
    with operated_fleet(
        kube, cluster, namespace, tmp_path, diagnostics, _objects(namespace), FLEET
    ) as ns:
        yield ns, time.monotonic() - start


def test_a_module_without_a_profile_is_profiled_by_jobs_then_placed(
    kube: Kube, profiled_fleet: tuple[str, float]
) -> None:
    ns, took = profiled_fleet
    prof = profiling_of(kube, ns, MODULE)
    (run,) = prof["runs"]
    assert run["hardwareType"] == "bed-robot" and run["state"] == "Profiled", run
    assert run["jobs"] == 3 and run["grid"] == 4
    # the Jobs used at least the work they measured (3 x 20 cycles x 10 ms of CPU)
    assert run["cpuSeconds"] >= 0.9 * 3 * 20 * WORK_MS / 1e3, run
    rows = {r["cpu"]: r for r in prof["rows"]}
    assert sorted(rows) == ["100m", "150m", "200m", "50m"]
    assert {c for c, r in rows.items() if r["source"] == "measured"} == {"50m", "100m", "200m"}
    assert rows["150m"]["source"] == "fitted"
    # what the real quota did: the work takes at least its CPU time, and 50m (5 ms of CPU per
    # 100 ms period) stretches 10 ms of work over several periods, where 200m runs it at once
    assert rows["200m"]["meanMillis"] >= 0.9 * WORK_MS, rows
    assert rows["50m"]["meanMillis"] > 3 * rows["200m"]["meanMillis"], rows
    # the fitted limit lies between its measured neighbours (the robot is a 400m computer:
    # its own quota per 10 ms slows 10 ms of work to ~25 ms whatever the pod's limit above it)
    near = sorted([rows["100m"]["meanMillis"], rows["200m"]["meanMillis"]])
    assert near[0] <= rows["150m"]["meanMillis"] <= near[1], rows
    assert run["fitErrorPercent"] is not None and run["fitErrorPercent"] >= 0
    # the fleet waited for it, said so, and was planned with it
    waited = events(kube, ns, "ProfilingPending", FLEET)
    assert waited and "mapper on bed-robot" in waited[0]["message"], waited
    assert events(kube, ns, "Profiled", MODULE)
    status = fleet(kube, ns, FLEET)["status"]
    assert conditions(fleet(kube, ns, FLEET))["Ready"]["status"] == "True"
    placed = {p["robot"]: p for p in status["placement"] if p["module"] == MODULE}
    assert set(placed) == set(ROBOTS)
    # recorded: the profiling Jobs are deleted
    wait_profiling_jobs_deleted(kube, ns)
    print(
        f"profiled and Ready {took:.1f} s after the apply; {run['message']}; "
        f"Jobs' wall time {run['wallSeconds']:.1f} s; placement {placed}"
    )
