"""The benchmark's schedule: arms, seeds, blocks and their alternating order (pure)."""

from __future__ import annotations

from collections import Counter

import pytest

from e2e.bench.real.protocol import DEFAULT_RUNS, Protocol, parse_arms


def test_the_default_schedule_is_the_issues_protocol() -> None:
    """Issue 49: nsga2, nsga2-static, k8s-default and k8s-requests x6, onboard x1 (sanity)."""
    runs = Protocol().schedule()
    assert Counter(r.arm for r in runs) == {
        "nsga2": 6, "nsga2-static": 6, "k8s-default": 6, "k8s-requests": 6, "onboard": 1
    }  # fmt: skip
    assert len(runs) == 25
    assert [r.seed for r in runs if r.arm == "nsga2"] == [1, 2, 3, 4, 5, 6]
    assert [r.position for r in runs] == list(range(len(runs)))
    assert Protocol().window_s == 60 and Protocol().warmup_s == 90
    # every block has one run of each six-run arm, in alternating order
    four = ["nsga2", "nsga2-static", "k8s-default", "k8s-requests"]
    for b in range(6):
        got = [r.arm for r in runs if r.block == b and r.arm != "onboard"]
        assert got == (four if b % 2 == 0 else four[::-1]), b
    # the sanity run of onboard comes once, in the first block
    assert [r.block for r in runs if r.arm == "onboard"] == [0]


def test_k8s_requests_hands_the_fleet_to_kube_scheduler_like_k8s_default() -> None:
    (run,) = Protocol(runs={"k8s-requests": 1}).schedule()
    assert run.algorithm == "k8s-default" and run.arm == "k8s-requests"
    # the Pending rule applies to kube-scheduler's arms only
    kinds = {r.arm: r.kube_scheduler for r in Protocol().schedule()}
    assert kinds == {
        "nsga2": False, "nsga2-static": False, "k8s-default": True, "k8s-requests": True,
        "onboard": False,
    }  # fmt: skip
    assert Protocol().as_json()["arms"] == {
        "nsga2": 6, "nsga2-static": 6, "k8s-default": 6, "k8s-requests": 6, "onboard": 1
    }  # fmt: skip


def test_static_plans_with_nsga2_and_no_closed_loop() -> None:
    runs = Protocol(runs={"nsga2-static": 1, "nsga2": 1}).schedule()
    static = next(r for r in runs if r.arm == "nsga2-static")
    nsga2 = next(r for r in runs if r.arm == "nsga2")
    assert static.algorithm == "nsga2" and not static.closed_loop
    assert nsga2.algorithm == "nsga2" and nsga2.closed_loop


def test_arms_are_read_with_counts_and_bad_ones_named() -> None:
    assert (
        parse_arms("nsga2=6,k8s-default=6,onboard=1,nsga2-static=6,k8s-requests=6") == DEFAULT_RUNS
    )
    assert parse_arms("onboard") == {"onboard": 1}
    with pytest.raises(ValueError, match="unknown arm 'random'"):
        parse_arms("random=2")
    with pytest.raises(ValueError, match="nsga2='x' is not a whole number"):
        parse_arms("nsga2=x")
    with pytest.raises(ValueError, match="at least 1"):
        parse_arms("nsga2=0")
