"""A robot's link judged from one window and remembered across windows (domain.linkhealth)."""

from __future__ import annotations

import pytest

from fogfleet.api.v1alpha1.linkhealth import LinkHealth, LinkState
from fogfleet.domain.linkhealth import (
    LinkSample,
    RobotLink,
    advance,
    judge,
    latency_limit,
    planned_links,
)
from fogfleet.domain.network import Link

WIFI = Link(latency=4e-3, jitter=1e-3, bandwidth=100e6)
SETTINGS = LinkHealth(latencyFactor=3, latencyMarginMillis=20, minAnsweredPercent=50)
STABLE = 60.0


def sample(one_way_ms: float | None, answered: float | None = 1.0) -> LinkSample:
    return LinkSample(answered, None if one_way_ms is None else 2 * one_way_ms / 1e3)


def step(prev: RobotLink | None, s: LinkSample, now: float, window: float = 0.0) -> RobotLink:
    return advance(prev, judge("robot-1", s, WIFI, SETTINGS), s, now, STABLE, window)


def test_the_limit_is_the_factor_times_the_declared_latency_plus_the_margin() -> None:
    assert latency_limit(WIFI, SETTINGS) == pytest.approx(0.032)


@pytest.mark.parametrize(
    ("s", "state"),
    [
        (LinkSample(None, None), LinkState.UNKNOWN),  # no pod of the robot is scraped
        (LinkSample(0.0, None), LinkState.LOST),  # nothing answered
        (sample(5), LinkState.HEALTHY),
        (sample(31), LinkState.HEALTHY),  # just under 3 x 4 + 20 ms
        (sample(33), LinkState.DEGRADED),
        (sample(5, answered=0.4), LinkState.DEGRADED),  # fast when it answers, but rarely
        (sample(5, answered=0.5), LinkState.HEALTHY),
    ],
)
def test_one_window_is_judged_against_the_declared_link(s: LinkSample, state: LinkState) -> None:
    assert judge("robot-1", s, WIFI, SETTINGS).state is state


def test_a_degraded_verdict_names_the_measure_the_declared_figure_and_the_limit() -> None:
    v = judge("robot-1", sample(150, answered=0.9), WIFI, SETTINGS)
    assert v.message == (
        "robot-1's link measured 150 ms one way (declared 4 ms, limit 32 ms), "
        "90% of scrapes answered"
    )
    assert v.measured == Link(latency=0.15, jitter=1e-3, bandwidth=100e6, loss=pytest.approx(0.1))


def test_a_measure_below_the_declared_latency_plans_with_the_declared_one() -> None:
    v = judge("robot-1", sample(1), WIFI, SETTINGS)
    assert v.measured is not None and v.measured.latency == WIFI.latency


def test_a_degraded_link_is_planned_with_its_measure_until_healthy_for_the_stable_window() -> None:
    s0 = step(None, sample(5), 0)
    assert s0.state is LinkState.HEALTHY and s0.planned is None
    s1 = step(s0, sample(150), 10)
    assert s1.state is LinkState.DEGRADED and s1.since == 10
    assert s1.planned is not None and s1.planned.latency == pytest.approx(0.15)
    s2 = step(s1, sample(5), 20)  # healthy again: not yet moved back
    assert s2.state is LinkState.RECOVERING and s2.planned == s1.planned
    assert s2.healthy_since == 20
    s3 = step(s2, sample(5), 20 + STABLE - 1)
    assert s3.state is LinkState.RECOVERING and s3.planned == s1.planned
    assert s3.since == 20  # the same state goes on
    s4 = step(s3, sample(5), 20 + STABLE)
    assert s4.state is LinkState.HEALTHY and s4.planned is None and s4.since == 20 + STABLE


def test_a_link_that_flaps_stays_planned_around_and_its_stable_window_starts_again() -> None:
    s = step(step(None, sample(150), 0), sample(5), 10)
    assert s.state is LinkState.RECOVERING
    s = step(s, sample(150), 40)  # bad again inside the stable window
    assert s.state is LinkState.DEGRADED and s.planned is not None
    s = step(s, sample(5), 50)
    assert s.state is LinkState.RECOVERING and s.healthy_since == 50
    assert step(s, sample(5), 10 + STABLE).state is LinkState.RECOVERING  # counted from 50


def test_small_changes_of_a_degraded_measure_keep_the_planned_link() -> None:
    s1 = step(None, sample(150), 0)
    s2 = step(s1, sample(200), 10)  # worse, but not 1.5 times: no re-plan for it
    assert s2.planned == s1.planned
    s3 = step(s2, sample(300), 20)  # 2 x the planned latency: planned with the new measure
    assert s3.planned is not None and s3.planned.latency == pytest.approx(0.3)


def test_a_lost_link_moves_nothing() -> None:
    s = step(step(None, sample(5), 0), LinkSample(0.0, None), 10)
    assert s.state is LinkState.LOST and s.planned is None
    back = step(s, sample(5), 70)
    assert back.state is LinkState.HEALTHY  # it was never planned around


def test_a_degraded_link_that_is_then_lost_keeps_its_planned_link() -> None:
    s = step(step(None, sample(150), 0), LinkSample(0.0, None), 10)
    assert s.state is LinkState.LOST and s.planned is not None
    assert step(s, sample(5), 20).state is LinkState.RECOVERING


def test_a_window_without_data_keeps_what_was_known() -> None:
    s1 = step(None, sample(150), 0)
    s2 = step(s1, LinkSample(None, None), 10)
    assert s2.state is LinkState.DEGRADED and s2.planned == s1.planned and s2.since == 0
    assert step(None, LinkSample(None, None), 0).state is LinkState.UNKNOWN


def test_planned_links_lists_only_the_robots_planned_with_a_measure() -> None:
    links = {"robot-1": step(None, sample(150), 0), "robot-2": step(None, sample(5), 0)}
    assert set(planned_links(links)) == {"robot-1"}


def test_too_few_answers_count_only_after_a_whole_window_of_them() -> None:
    healthy = step(None, sample(5), 0, 10)
    s = step(healthy, sample(5, answered=0.4), 2, 10)  # a cut beginning: some unanswered
    assert s.state is LinkState.HEALTHY and s.sparse_since == 2
    s = step(s, LinkSample(0.0, None), 4, 10)  # then nothing answers: lost, nothing moved
    assert s.state is LinkState.LOST and s.planned is None and s.sparse_since is None
    s = step(s, sample(5, answered=0.3), 64, 10)  # the cut ends: the window still holds it
    assert s.state is LinkState.LOST and s.planned is None
    s = step(s, sample(5, answered=0.6), 70, 10)
    assert s.state is LinkState.HEALTHY and s.planned is None


def test_a_link_that_answers_too_rarely_for_a_whole_window_is_degraded() -> None:
    s = step(step(None, sample(5), 0, 10), sample(5, answered=0.3), 10, 10)
    assert s.state is LinkState.HEALTHY
    s = step(s, sample(5, answered=0.3), 20, 10)
    assert s.state is LinkState.DEGRADED and s.planned is not None
    assert s.planned.loss == pytest.approx(0.7)


def test_a_slow_link_is_degraded_once_it_has_been_slow_for_a_whole_window() -> None:
    healthy = step(None, sample(5), 0, 10)
    s = step(healthy, sample(150, answered=0.3), 2, 10)
    assert s.state is LinkState.HEALTHY and s.slow_since == 2 and s.planned is None
    s = step(s, sample(150), 8, 10)
    assert s.state is LinkState.HEALTHY
    s = step(s, sample(150), 12, 10)
    assert s.state is LinkState.DEGRADED and s.planned is not None and s.since == 12


def test_a_new_fleets_slow_first_window_moves_nothing() -> None:
    # the pods' exporters are starting: their first scrapes are slow, the next ones are not
    s = step(None, sample(112), 0, 10)
    assert s.state is LinkState.UNKNOWN and s.planned is None
    s = step(s, sample(10), 2, 10)
    assert s.state is LinkState.HEALTHY and s.planned is None and s.slow_since is None
    assert step(s, sample(150), 4, 10).state is LinkState.HEALTHY  # its clock starts again


def test_a_link_planned_around_follows_its_measure_at_once() -> None:
    s = step(step(step(None, sample(150), 0), sample(5), 10, 10), sample(150), 12, 10)
    assert s.state is LinkState.DEGRADED  # was Recovering: already planned around
