"""The benchmark's schedule: arms, seeds, blocks and their alternating order (pure)."""

from __future__ import annotations

from collections import Counter

import pytest

from e2e.bench.real.protocol import DEFAULT_RUNS, Protocol, parse_arms


def test_the_default_schedule_is_the_issues_protocol() -> None:
    runs = Protocol().schedule()
    assert Counter(r.arm for r in runs) == {
        "nsga2": 6, "k8s-default": 6, "onboard": 2, "nsga2-static": 3
    }  # fmt: skip
    assert [r.seed for r in runs if r.arm == "nsga2"] == [1, 2, 3, 4, 5, 6]
    assert [r.position for r in runs] == list(range(len(runs)))
    assert Protocol().window_s == 60 and Protocol().warmup_s == 90
    # every block has one nsga2 and one k8s-default run, in alternating order
    for b in range(6):
        pair = [r.arm for r in runs if r.block == b and r.arm in ("nsga2", "k8s-default")]
        assert pair == (["nsga2", "k8s-default"] if b % 2 == 0 else ["k8s-default", "nsga2"])
    # the smaller arms are spread over the blocks, not bunched at the start
    assert [r.block for r in runs if r.arm == "onboard"] == [0, 3]
    assert [r.block for r in runs if r.arm == "nsga2-static"] == [0, 2, 4]


def test_static_plans_with_nsga2_and_no_closed_loop() -> None:
    runs = Protocol(runs={"nsga2-static": 1, "nsga2": 1}).schedule()
    static = next(r for r in runs if r.arm == "nsga2-static")
    nsga2 = next(r for r in runs if r.arm == "nsga2")
    assert static.algorithm == "nsga2" and not static.closed_loop
    assert nsga2.algorithm == "nsga2" and nsga2.closed_loop


def test_arms_are_read_with_counts_and_bad_ones_named() -> None:
    assert parse_arms("nsga2=6,k8s-default=6,onboard=2,nsga2-static=3") == DEFAULT_RUNS
    assert parse_arms("onboard") == {"onboard": 1}
    with pytest.raises(ValueError, match="unknown arm 'random'"):
        parse_arms("random=2")
    with pytest.raises(ValueError, match="nsga2='x' is not a whole number"):
        parse_arms("nsga2=x")
    with pytest.raises(ValueError, match="at least 1"):
        parse_arms("nsga2=0")
