"""A split network whose times are measured, not declared (issue 48, item 4), on the bed's real
nodes: the pose estimator declares its split points' names and its bounds only, with
``profiling: {mode: auto}``. The operator runs one profiling Job of the module's own image per
hardware type it needs (the robots' ``bed-robot`` for the heads and the local model, the
edge's ``bed-edge`` for the tails); each times every part of the image's network there and
the fleet is planned with what they measured.
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
from e2e.tests.dnnbed import DNN, FLEET, MODULE, profiled_objects
from e2e.tests.rosbed import EDGE, ROBOTS, operated_fleet

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("real nodes: profiling Jobs of the workload image on the robots and edge"),
    pytest.mark.real,
    pytest.mark.dnnsplit,
    pytest.mark.timeout(600),
]

FRAMES = 20
FRAME_BYTES = 224 * 224 * 3  # the image's network takes 224x224 RGB frames (uint8)


@pytest.fixture
def profiled_split(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[tuple[str, float]]:
    start = time.monotonic()
    objects = profiled_objects(namespace, FRAMES)
    with operated_fleet(kube, cluster, namespace, tmp_path, diagnostics, objects, FLEET) as ns:
        yield ns, time.monotonic() - start


def test_the_network_is_timed_per_hardware_type_and_planned_with_what_was_measured(
    kube: Kube, profiled_split: tuple[str, float]
) -> None:
    ns, took = profiled_split
    prof = profiling_of(kube, ns, MODULE)
    runs = {r["hardwareType"]: r for r in prof["runs"]}
    assert set(runs) == {"bed-robot", "bed-edge"}, runs
    assert all(r["state"] == "Profiled" and r["jobs"] == 1 for r in runs.values()), runs
    measured = {p["hardwareType"]: p for p in prof["dnn"]}
    names = [p["name"] for p in DNN["splitPoints"]]
    for hw, got in measured.items():
        # the byte counts are the network's: the same on every type
        assert got["inputBytes"] == FRAME_BYTES and got["frames"] == FRAMES, got
        assert [p["name"] for p in got["splitPoints"]] == names, got
        bytes_at = {p["name"]: p["tensorBytes"] for p in got["splitPoints"]}
        assert bytes_at["bneck"] == 8 * 14 * 14 * 4 < bytes_at["b6"], got  # 8 float32 channels
        # CPU time of real work: every part takes time, a head and its tail together take
        # about the whole network, the local model (width 0.25) far less
        for p in got["splitPoints"]:
            assert 0 < p["headMillis"] < got["fullMillis"], (hw, p)
            whole = p["headMillis"] + p["tailMillis"]
            assert 0.5 * got["fullMillis"] < whole < 2 * got["fullMillis"], (hw, p)
        assert 0 < got["localMillis"] < got["fullMillis"], got
    # the fleet waited for its profiles, said so, and was planned with them
    waited = events(kube, ns, "ProfilingPending", FLEET)
    assert waited and f"{MODULE} on bed-" in waited[0]["message"], waited
    assert conditions(fleet(kube, ns, FLEET))["Ready"]["status"] == "True"
    placed = {p["robot"]: p for p in fleet(kube, ns, FLEET)["status"]["placement"]
              if p["module"] == MODULE}  # fmt: skip
    assert set(placed) == set(ROBOTS)
    for entry in placed.values():
        # 100 Mbit/s, 4 + 1 ms: bneck (the raw frame is 24 times its tensor)
        assert entry["node"] == EDGE and entry["split"]["action"] == "bneck", entry
    wait_profiling_jobs_deleted(kube, ns)
    print(
        f"profiled and Ready {took:.1f} s after the apply; "
        + "; ".join(f"{hw}: {r['message']}" for hw, r in sorted(runs.items()))
    )
