"""Admission and routing: tinyKube III-B, privacy first."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fogfleet.autoscaling.dispatch import (
    Tier,
    TierLoad,
    estimate_response_seconds,
    plan_dispatch,
    route,
)

EDGE = Tier("edge", service_rate=6.0, accepts_private=True)
CLOUD = Tier("cloud", service_rate=5.0, network_delay_seconds=0.02)


def test_estimate_counts_only_the_queue_ahead() -> None:
    assert estimate_response_seconds(2, 4, 5.0) == pytest.approx(0.2)  # idle replica
    # 6 present, 4 replicas: waits for 3 departures at rate 20/s, then 0.2 s of service
    assert estimate_response_seconds(6, 4, 5.0, 0.01) == pytest.approx(0.01 + 0.15 + 0.2)
    assert estimate_response_seconds(0, 0, 5.0) == math.inf


def test_normal_traffic_goes_edge_first_then_cloud() -> None:
    tiers = [EDGE, CLOUD]
    assert route(False, 0.4, tiers, [TierLoad(3, 0), TierLoad(3, 0)]) == 0
    assert route(False, 0.4, tiers, [TierLoad(3, 30), TierLoad(3, 0)]) == 1
    assert route(False, 0.4, tiers, [TierLoad(3, 30), TierLoad(3, 30)]) is None


def test_private_traffic_is_rejected_rather_than_sent_to_cloud() -> None:
    tiers = [EDGE, CLOUD]
    assert route(True, 0.4, tiers, [TierLoad(3, 30), TierLoad(9, 0)]) is None


@given(
    edge=st.tuples(st.integers(0, 20), st.integers(0, 60)),
    cloud=st.tuples(st.integers(0, 20), st.integers(0, 60)),
    target=st.floats(0.05, 2.0),
    reserve=st.integers(0, 5),
)
def test_private_traffic_never_reaches_a_tier_without_privacy(
    edge: tuple[int, int], cloud: tuple[int, int], target: float, reserve: int
) -> None:
    chosen = route(True, target, [CLOUD, EDGE], [TierLoad(*cloud), TierLoad(*edge)], reserve)
    assert chosen in (None, 1)


def test_reserve_keeps_the_last_places_for_private_requests() -> None:
    tiers = [EDGE, CLOUD]
    # edge: 2 replicas, 3 present -> estimate 2/12 + 1/6 = 0.333 s; with 2 phantom places 0.5 s
    loads = [TierLoad(2, 3), TierLoad(2, 0)]
    assert route(False, 0.4, tiers, loads, reserve=0) == 0
    assert route(False, 0.4, tiers, loads, reserve=2) == 1
    assert route(True, 0.4, tiers, loads, reserve=2) == 0


def test_plan_conserves_the_offered_rate() -> None:
    plan = plan_dispatch(20.0, 50.0, [EDGE, CLOUD], [4, 3], [0.4, 0.4], reserve=1)
    total = sum(plan.tier_rates) + plan.private_rejected + plan.normal_rejected
    assert total == pytest.approx(70.0)
    assert plan.private_rejected > 0 and plan.normal_rejected > 0


def test_plan_sends_private_traffic_only_to_private_tiers() -> None:
    plan = plan_dispatch(30.0, 0.0, [EDGE, CLOUD], [1, 19], [0.4, 0.4])
    assert plan.tier_rates[1] == 0.0
    assert plan.private_rejected > 20.0
