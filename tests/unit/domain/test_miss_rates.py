"""One format for miss rates and one worst module (domain.miss_rates)."""

from __future__ import annotations

import math

import pytest

from fogfleet.domain.miss_rates import format_miss_rate, pooled_miss_rate, worst_module


@pytest.mark.parametrize(
    ("rate", "shown"),
    [
        (0.00007, "0.007%"),  # issue 36: a hard real-time prediction, never "0.00%"
        (0.0000042, "0.00042%"),
        (0.049, "4.9%"),
        (0.5, "50.0%"),
        (1.0, "100.0%"),
        (0.0031, "0.31%"),
        (0.0, "0%"),
        (2e-24, "<0.0001%"),
        (None, "-"),
        (math.nan, "-"),
    ],
)
def test_a_miss_rate_reads_as_a_percentage_that_shows_small_rates(
    rate: float | None, shown: str
) -> None:
    assert format_miss_rate(rate) == shown


def test_a_rate_that_is_not_zero_never_reads_as_zero() -> None:
    for exponent in range(-12, 1):
        assert format_miss_rate(10.0**exponent) not in ("0%", "0.00%", "-")


def test_the_worst_module_has_the_highest_rate() -> None:
    assert worst_module({"a": 0.01, "b": 0.2, "c": 0.1}) == "b"


def test_an_unplaced_module_is_worse_than_any_rate() -> None:
    assert worst_module({"a": 0.9}, unplaced=["z"]) == "z"


def test_tied_rates_go_to_the_highest_prediction_then_the_name() -> None:
    simulated = {"a": 0.0, "b": 0.0, "c": 0.0}  # a short simulation saw no miss
    assert worst_module(simulated, {"a": 1e-9, "b": 4e-6, "c": 3e-7}) == "b"
    assert worst_module(simulated) == "a"
    assert worst_module({"b": 0.1, "a": 0.1}, {"a": 0.2, "b": 0.2}) == "a"


def test_a_module_that_ran_no_cycle_is_not_the_worst() -> None:
    assert worst_module({"a": math.nan, "b": 0.0, "c": None}, {"a": 0.5}) == "b"
    assert worst_module({}) is None


def test_pooled_rates_weigh_each_by_its_cycles() -> None:
    # 23 of 284 and 5 of 302 missed: 28 of 586, not the mean of 8.1 % and 1.7 %
    pooled = pooled_miss_rate([(23 / 284, 284.0), (5 / 302, 302.0)])
    assert pooled == pytest.approx(28 / 586)


def test_nothing_measured_pools_to_none_never_zero() -> None:
    assert pooled_miss_rate([]) is None
    assert pooled_miss_rate([(None, 0.0), (0.5, 0.0), (math.nan, 100.0)]) is None
    assert pooled_miss_rate([(0.0, 300.0), (None, 0.0)]) == 0.0  # measured, none missed
