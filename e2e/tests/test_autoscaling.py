"""SLO-driven autoscaling end to end, one decision at a time: the real Prometheus of the harness
scrapes the twin, the scaling controller decides against the real API server (the rig:
``scaling_rig``), with short windows in the test's ScalingSpec so the suite stays fast. The
whole loop, with the operator deciding on its own, is ``test_autoscaling_loop``.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import pytest

from e2e.bed.operator_fixtures import free_port
from e2e.tests.scaling_rig import (
    DOWN_POLICY,
    DOWN_WINDOW,
    PERIOD,
    Rig,
    module_body,
    start_twin,
    total,
)
from fogfleet.adapters.prometheus import PrometheusClient

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus (file_sd targets) and its kwok warehouse nodes"),
    pytest.mark.timeout(300),
]  # ticks are slower on a loaded 2-core bed


def test_load_step_scales_up_within_the_window_and_down_after_stabilisation(
    rig: Rig, tmp_path: Path
) -> None:
    rig.kube.apply(module_body(rig.namespace))
    rig.tick()  # the first decision places the starting pools (edge 1, cloud 1)
    start_twin(rig, tmp_path, rate=4.0)
    base = rig.ticks_until(
        "a decision on real metrics",
        lambda s: (s.get("scaling") or {}).get("metricsAvailable") is True,
        timeout=30,
    )["scaling"]["desiredReplicas"]

    rig.set_load(60.0)
    t_step = time.monotonic()
    up = rig.ticks_until(
        "a scale-up after the load step",
        lambda s: s["scaling"]["desiredReplicas"] > base,
        timeout=6 + 2 * PERIOD + 10,  # rate window + scrape + decision, with slack
    )
    took = time.monotonic() - t_step
    print(f"scale-up {base} -> {up['scaling']['desiredReplicas']} after {took:.1f}s")
    assert rig.events("ScaledUp")
    assert {c: v["status"] for c, v in rig.conditions().items()} == {
        "Scaling": "True",
        "MetricsUnavailable": "False",
    }
    # the predictive sizing fills the edge pool before the cloud's (here, edge max 6)
    settled = rig.ticks_until(
        "the edge pool to fill",
        lambda s: {p["tier"]: p["replicas"] for p in s["scaling"]["pools"]}["edge"] == 6,
        timeout=20,
    )
    peak = settled["scaling"]["desiredReplicas"]
    assert peak > 6, settled  # 60 requests/s need the cloud too

    rig.set_load(2.0)
    t_fall = time.monotonic()
    rig.ticks_until(
        "the first scale-down",
        lambda s: s["scaling"]["desiredReplicas"] < peak,
        timeout=DOWN_WINDOW + 6 + 20,
    )
    first_down = time.monotonic() - t_fall
    print(f"first scale-down {first_down:.1f}s after the load fell")
    assert first_down >= DOWN_WINDOW  # not before the stabilisation window
    for _ in range(int(2 * DOWN_POLICY["periodSeconds"] / PERIOD) + 1):
        time.sleep(PERIOD)
        rig.tick()
    # at most `value` pods removed per pool and policy period
    after = [(t, p) for t, p in rig.history if t >= t_fall]
    for tier in ("edge", "cloud"):
        for (t1, a), (t2, b) in itertools.combinations(after, 2):
            if t2 - t1 < DOWN_POLICY["periodSeconds"] - 0.5:
                assert a[tier] - b[tier] <= DOWN_POLICY["value"], (tier, after)
    assert total(after[-1][1]) < peak
    assert rig.events("ScaledDown")


def test_prometheus_unreachable_holds_then_scaling_resumes(rig: Rig, tmp_path: Path) -> None:
    rig.kube.apply(module_body(rig.namespace))
    rig.tick()
    start_twin(rig, tmp_path, rate=4.0)
    held = rig.ticks_until(
        "a decision on real metrics",
        lambda s: (s.get("scaling") or {}).get("metricsAvailable") is True,
        timeout=30,
    )["scaling"]["desiredReplicas"]
    live = rig.deps.prometheus
    dead_port = free_port()  # nothing listens there
    rig.deps.prometheus = PrometheusClient(f"http://127.0.0.1:{dead_port}")
    rig.set_load(60.0)  # would scale up, if the scaler could see it
    for _ in range(4):
        status = rig.tick()
        assert status["scaling"]["desiredReplicas"] == held
        assert status["scaling"]["metricsAvailable"] is False
        time.sleep(PERIOD)
    cond = rig.conditions()["MetricsUnavailable"]
    assert (cond["status"], cond["reason"]) == ("True", "PrometheusUnreachable")
    assert f"127.0.0.1:{dead_port}" in cond["message"]
    assert rig.conditions()["Scaling"]["status"] == "False"
    # one Warning for the outage (another came earlier, for the NoData before the twin ran)
    outage = [e for e in rig.events("MetricsUnavailable") if str(dead_port) in e["message"]]
    assert len(outage) == 1 and outage[0]["type"] == "Warning"
    assert not rig.events("ScaledUp")

    rig.deps.prometheus = live
    rig.ticks_until(
        "scaling to resume", lambda s: s["scaling"]["desiredReplicas"] > held, timeout=20
    )
    assert rig.conditions()["MetricsUnavailable"]["status"] == "False"


def test_a_bad_slo_query_is_reported_precisely_and_nothing_scales(rig: Rig) -> None:
    query = (
        "histogram_quantile(0.99, sum by (le) (rate(fogfleet_response_time_seconds_bucket[10s]))"
    )
    slo = {"query": query, "targetMillis": 350}
    rig.kube.apply(module_body(rig.namespace, mode="reactive", slo=slo))
    for _ in range(2):
        status = rig.tick()
        time.sleep(0.5)
    assert status["scaling"]["desiredReplicas"] == 2  # edge 1 + cloud 1, as started
    cond = rig.conditions()["MetricsUnavailable"]
    assert (cond["status"], cond["reason"]) == ("True", "InvalidSLOQuery")
    assert cond["message"].startswith("spec.scaling.slo.query: ")
    assert "parse error" in cond["message"] and query in cond["message"]
    events = rig.events("InvalidSLOQuery")
    assert len(events) == 1 and events[0]["type"] == "Warning"
    assert "parse error" in events[0]["message"]
    assert not rig.events("ScaledUp") and not rig.events("ScaledDown")
