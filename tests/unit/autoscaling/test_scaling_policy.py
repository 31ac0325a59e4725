"""Policies and the shared guard rails of decide()."""

import math

import pytest

from fogfleet.autoscaling.behavior import TINYKUBE_BEHAVIOR
from fogfleet.autoscaling.policy import (
    MetricsSnapshot,
    Pool,
    Predictive,
    ReactiveCpu,
    ReactiveSlo,
    ScaleDecision,
    ScalerState,
    TierMetrics,
    decide,
    hpa_replicas,
    size_pools,
)

EDGE = Pool("edge", 1, 17, math.log(10) / 0.35, 0.35, 0.99, 1.8, accepts_private=True)
CLOUD = Pool("cloud", 1, 19, math.log(10) / 0.4845, 0.35, 0.99, 4.7, 0.0155)
POOLS = (EDGE, CLOUD)


def snap(t: float, edge: TierMetrics, cloud: TierMetrics, **rates: float) -> MetricsSnapshot:
    return MetricsSnapshot(t, (edge, cloud), rates.get("p"), rates.get("n"))


def test_hpa_formula_matches_the_docs_example() -> None:
    # docs: current 200m, desired 100m -> replicas double
    assert hpa_replicas(2, 2, 2.0) == 4
    assert hpa_replicas(10, 10, 0.5) == 5
    assert hpa_replicas(10, 10, 1.05) == 10  # within the 10 % tolerance


def test_hpa_counts_unready_pods_as_idle_when_scaling_up() -> None:
    # 4 ready at 150 %, 4 starting: (1.5 * 4) / 8 = 0.75 < 1 -> no further scale-up
    assert hpa_replicas(8, 4, 1.5) == 8
    # 6 ready at 200 %, 2 starting: 12/8 = 1.5 -> ceil(1.5 * 8) = 12
    assert hpa_replicas(8, 6, 2.0) == 12


def test_reactive_cpu_scales_each_tier_by_its_utilisation() -> None:
    s = snap(0, TierMetrics("edge", 5, 5, cpu_utilization=1.0), TierMetrics("cloud", 5, 5, 0.2))
    rec = ReactiveCpu(0.8).recommend(s, POOLS, None)
    assert rec is not None
    assert rec[0] == {"edge": 7, "cloud": 2}


def test_missing_metrics_hold_the_last_decision_and_say_so() -> None:
    last = ScaleDecision(0.0, {"edge": 9, "cloud": 4}, "earlier")
    s = snap(15, TierMetrics("edge", 9, 9), TierMetrics("cloud", 4, 4))
    decision, state = decide(ReactiveCpu(), s, POOLS, ScalerState(last=last))
    assert decision.metrics_missing
    assert dict(decision.replicas) == {"edge": 9, "cloud": 4}
    assert state.last == decision


def test_missing_metrics_never_hold_below_the_floor() -> None:
    pools = (Pool("edge", 0, 5, 6.0, 0.4), Pool("cloud", 3, 5, 6.0, 0.4))
    s = snap(0, TierMetrics("edge", 0, 0), TierMetrics("cloud", 0, 0))
    decision, _ = decide(ReactiveSlo(), s, pools, ScalerState(), safety_relevant=True)
    assert decision.metrics_missing
    assert dict(decision.replicas) == {"edge": 1, "cloud": 3}


def test_decisions_stay_within_bounds() -> None:
    state = ScalerState()
    for t, u in enumerate([5.0, 0.0, 3.0, 0.01, 9.0]):
        s = snap(
            t * 15.0,
            TierMetrics("edge", 5, 5, cpu_utilization=u),
            TierMetrics("cloud", 5, 5, cpu_utilization=u),
        )
        decision, state = decide(ReactiveCpu(), s, POOLS, state, behavior=TINYKUBE_BEHAVIOR)
        for pool in POOLS:
            assert pool.min_replicas <= decision.replicas[pool.name] <= pool.max_replicas


def test_safety_relevant_service_never_goes_to_zero() -> None:
    pools = (Pool("edge", 0, 5, 6.0, 0.4, accepts_private=True),)
    s = MetricsSnapshot(0, (TierMetrics("edge", 2, 2, cpu_utilization=0.0),), 0.0, 0.0)
    unsafe, _ = decide(ReactiveCpu(), s, pools, ScalerState())
    safe, _ = decide(ReactiveCpu(), s, pools, ScalerState(), safety_relevant=True)
    assert unsafe.replicas["edge"] == 0
    assert safe.replicas["edge"] == 1


def test_predictive_grows_with_demand_and_keeps_private_on_edge() -> None:
    small = size_pools(5.0, 10.0, POOLS, 2)
    large = size_pools(30.0, 60.0, POOLS, 2)
    assert all(a <= b for a, b in zip(small, large, strict=True))
    assert sum(large) > sum(small)
    # private-only demand needs no cloud replicas beyond the minimum
    assert size_pools(30.0, 0.0, POOLS, 2)[1] == CLOUD.min_replicas


def test_predictive_needs_rates() -> None:
    s = snap(0, TierMetrics("edge", 5, 5), TierMetrics("cloud", 5, 5), p=None, n=3.0)
    assert Predictive().recommend(s, POOLS, None) is None


def test_predictive_overload_asks_for_everything() -> None:
    s = snap(0, TierMetrics("edge", 5, 5), TierMetrics("cloud", 5, 5), p=500.0, n=500.0)
    rec = Predictive().recommend(s, POOLS, None)
    assert rec is not None
    assert rec[0] == {"edge": 17, "cloud": 19}


def test_predictive_trend_sizes_ahead_of_a_rising_rate() -> None:
    before = snap(0, TierMetrics("edge", 5, 5), TierMetrics("cloud", 5, 5), p=5.0, n=10.0)
    now = snap(5, TierMetrics("edge", 5, 5), TierMetrics("cloud", 5, 5), p=15.0, n=30.0)
    flat = Predictive().recommend(now, POOLS, before)
    ahead = Predictive(trend=True).recommend(now, POOLS, before)
    assert flat is not None and ahead is not None
    assert sum(ahead[0].values()) > sum(flat[0].values())


def test_pool_rejects_inverted_bounds() -> None:
    with pytest.raises(ValueError, match="min_replicas"):
        Pool("edge", 5, 2, 1.0, 1.0)
