"""The twin's tally: what a service's requests met, counted as the autoscaling bench counts."""

from __future__ import annotations

import math

from fogfleet.autoscaling.policy import Pool
from fogfleet.twin.model import Rejected, Served, ServiceSim
from fogfleet.twin.tally import Tally

MU = math.log(10) / 0.35
EDGE = Pool("edge", 1, 17, MU, 0.35, 0.99, setup_seconds=1.8, accepts_private=True)
CLOUD = Pool("cloud", 1, 19, MU, 0.5, 0.99, setup_seconds=4.7, network_delay_seconds=0.0155)


def test_a_request_is_late_only_past_its_own_target() -> None:
    assert Served("edge", False, 0.41, 0.40).late
    assert not Served("edge", False, 0.39, 0.40).late
    assert not Served("edge", False, 9.0).late  # no target: never late


def test_figures_are_the_benchs_fractions_per_class_and_of_answered_requests() -> None:
    records = [
        Rejected(True, "slo"), Served("edge", True, 0.2, 0.35), Served("edge", True, 0.2, 0.35),
        Served("edge", True, 0.2, 0.35),
        Rejected(False, "capacity"), *[Served("cloud", False, 0.6, 0.5)] * 2,
        *[Served("cloud", False, 0.1, 0.5)] * 7,
    ]  # fmt: skip
    t = Tally().add(records)
    assert (t.private_arrived, t.private_rejected, t.normal_arrived, t.normal_rejected) == (
        4, 1, 10, 1)  # fmt: skip
    assert t.figures() == {"privacyRejected": 0.25, "normalRejected": 0.1, "sloViolations": 2 / 12}
    assert Tally().figures() == {"privacyRejected": 0, "normalRejected": 0, "sloViolations": 0}


def test_since_counts_only_what_came_after_an_earlier_read() -> None:
    first = Tally().add([Rejected(False, "slo")])
    later = first.add([Served("edge", False, 0.1, 0.4)])
    assert later.since(first) == Tally(normal_arrived=1, served=1)


def test_the_simulation_draws_each_requests_target_from_the_pools_targets() -> None:
    s = ServiceSim([EDGE, CLOUD], seed=3, reserve=2)
    s.set_replicas("edge", 4)
    s.set_replicas("cloud", 4)
    answered = [r for r in s.advance(600.0, 1.0, 2.0) if isinstance(r, Served)]
    targets = [r.target_seconds for r in answered]
    assert len(answered) > 500
    assert 0.35 <= min(targets) < 0.36 and 0.49 < max(targets) <= 0.5
    late = Tally().add(answered).figures()["sloViolations"]
    # a nearly idle pool answers exp(-mu t) of its requests past t: 10 % past 0.35 s and 3.7 %
    # past 0.5 s (mu = ln 10 / 0.35), about 6.4 % past a target drawn from 0.35-0.5
    assert 0.04 < late < 0.09, late
