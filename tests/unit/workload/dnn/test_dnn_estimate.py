"""The head's link estimate and the parts' measured times, in the rule's terms."""

from __future__ import annotations

import math

import pytest
from runspecs import SPEC

from fogfleet.contract.dnnsplit import actions
from fogfleet.workload.dnn.estimate import Ewma, LinkEstimator, PartTimes
from fogfleet.workload.dnn.runspec import DnnRunSpec


def test_an_ewma_starts_at_its_first_sample_then_moves_a_fifth_of_the_way() -> None:
    e = Ewma(0.2)
    assert e.add(10.0) == 10.0
    assert e.add(20.0) == pytest.approx(12.0)


def test_nothing_is_known_before_a_probe_and_an_answer() -> None:
    est = LinkEstimator()
    assert est.link() is None and not est.echoed
    est.echo(0.010)
    assert est.echoed and est.link() is None  # the bandwidth is still unknown


def test_probes_give_the_latency_and_answers_the_bandwidth() -> None:
    """A 20 ms round trip with nothing to carry; a frame of 10 000 B out and back that took
    20 ms + 8 ms of transfer + 5 ms on the tail: 10 kB x 8 / 8 ms = 10 Mbit/s."""
    est = LinkEstimator()
    est.echo(0.020)
    est.answer(round_trip_s=0.033, tail_s=0.005, moved_bytes=10_000)
    link = est.link()
    assert link is not None
    assert link.latency == pytest.approx(0.010)
    assert link.bandwidth == pytest.approx(10e6)


def test_a_transfer_too_quick_to_time_gives_a_large_finite_bandwidth() -> None:
    est = LinkEstimator()
    est.echo(0.002)
    est.answer(round_trip_s=0.0015, tail_s=0.001, moved_bytes=6272)
    link = est.link()
    assert link is not None and math.isfinite(link.bandwidth) and link.bandwidth > 1e9


def test_the_estimate_follows_a_slower_link_within_a_few_frames() -> None:
    est = LinkEstimator()
    est.echo(0.002)
    for _ in range(3):
        est.answer(0.002 + 0.001, 0.0, 10_000)  # 80 Mbit/s
    fast = est.link()
    for _ in range(10):
        est.answer(0.002 + 0.040, 0.0, 10_000)  # 2 Mbit/s
    slow = est.link()
    assert fast is not None and slow is not None
    assert fast.bandwidth > 40e6 and slow.bandwidth < 3e6


def _parts() -> PartTimes:
    run = DnnRunSpec.from_raw(SPEC)
    return PartTimes(run.model, robot_factor=2.0, tail_factor=0.5)


def test_without_measurements_the_plans_factors_and_the_declared_times_hold() -> None:
    parts = _parts()
    model, robot, tail = parts.model_now()
    assert (robot, tail) == (2.0, 0.5) and model == parts.model


def test_a_measured_part_is_predicted_at_its_measured_time() -> None:
    parts = _parts()
    parts.ran_head(2, 0.006)  # bneck's head: 6 ms on the robot (declared 2 ms)
    parts.ran_tail(2, 0.0012)  # bneck's tail: 1.2 ms on the tail node (declared 1.2 ms)
    model, robot, tail = parts.model_now()
    assert robot == pytest.approx(3.0) and tail == pytest.approx(1.0)
    acts = actions(model, None, robot, tail)
    assert acts[2].robot_s == pytest.approx(0.006)  # measured
    # unmeasured parts scale by what the measured ones on their side say
    assert acts[1].robot_s == pytest.approx(0.002 * 3.0)
    assert acts[3].robot_s == pytest.approx(0.0004 * 3.0)
