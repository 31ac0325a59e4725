from __future__ import annotations

import numpy as np
import pytest

from fogfleet.scheduling.choice import choose, non_dominated


def test_non_dominated_drops_dominated_and_duplicate_rows() -> None:
    F = np.array([[1.0, 2.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]])
    assert non_dominated(F).tolist() == [0, 1]


def test_lexicographic_follows_objective_order_and_breaks_ties() -> None:
    F = np.array([[0.1, 5.0, 1.0], [0.1, 3.0, 9.0], [0.2, 0.0, 0.0]])
    idx, reason = choose(F, ["missRate", "onboard", "reserve"])
    assert idx == 1
    assert reason.startswith("lowest missRate 0.1 among 3 non-dominated plans")
    assert "ties broken by onboard 3" in reason


def test_weighted_uses_min_max_normalised_objectives() -> None:
    F = np.array([[0.0, 100.0], [1.0, 0.0], [0.4, 40.0]])
    assert choose(F, ["a", "b"], "weighted", {"a": 1.0, "b": 1.0})[0] == 2
    assert choose(F, ["a", "b"], "weighted", {"a": 10.0, "b": 1.0})[0] == 0
    assert choose(F, ["a", "b"], "weighted", {"a": 0.0, "b": 1.0})[0] == 1  # a left out


def test_weighted_reaches_a_plan_in_a_concave_part_of_the_front() -> None:
    """A weighted sum can only pick the ends of a concave front; the ASF picks the middle."""
    F = np.array([[0.0, 1.0], [0.6, 0.6], [1.0, 0.0]])
    idx, reason = choose(F, ["a", "b"], "weighted", {"a": 1.0, "b": 1.0})
    assert idx == 1 and "ASF" in reason


def test_knee_picks_the_bulge_of_a_convex_front() -> None:
    F = np.array([[0.0, 1.0], [0.1, 0.1], [0.5, 0.05], [1.0, 0.0]])
    idx, reason = choose(F, ["a", "b"], "knee")
    assert idx == 1
    assert "knee" in reason


def test_unknown_rule_is_rejected() -> None:
    with pytest.raises(ValueError):
        choose(np.zeros((2, 1)), ["a"], "best")


def test_the_lexicographic_reason_quotes_the_chosen_plans_values() -> None:
    """Issue 35: two plans tie on missRate within the tolerance; the one with the lower
    onboard wins, and the reason gives its missRate, not the best tied value."""
    F = np.array([[1.0, 5.0], [1.0009, 3.0]])
    idx, reason = choose(F, ["missRate", "onboard"])
    assert idx == 1
    assert reason.startswith("missRate 1.001, within 0.001001 of the lowest 1 among 2")
    assert "ties broken by onboard 3" in reason
