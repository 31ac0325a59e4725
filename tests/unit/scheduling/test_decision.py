"""Which plan a fleet gets (``scheduling.decision.decide``): checked, and what runs kept unless
the new plan is better by the migration margin."""

from __future__ import annotations

import numpy as np
import pytest

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible
from fogfleet.scheduling.decision import CorePlanner, Decision, decide, fingerprint, with_defaults

from .conftest import Fixed

SETTINGS = SchedulerSettings(population=16, generations=10, seed=1)


def _decide(problem: Problem, planner: CorePlanner, before: list[int]) -> Decision:
    fp = fingerprint(problem, SETTINGS)
    return decide(
        planner, problem, SETTINGS, fleet="f", fp=fp, before=np.array(before, dtype=np.int64)
    )


def test_a_decision_reports_the_deployed_placement_and_its_moves(tiny: Problem) -> None:
    decision = _decide(tiny, CorePlanner(), [0, 0, 0])
    assert decision.placement.shape == (3,) and (decision.placement >= 0).all()
    assert decision.placement[0] == 0  # pinned on board
    moved = [i for i in range(3) if decision.placement[i] != 0]
    assert decision.migrations == len(moved) == len(decision.moves)
    assert decision.fingerprint == fingerprint(tiny, SETTINGS) and len(decision.plan_id) == 12
    assert set(decision.objectives) >= {"missRate"}


def test_a_plan_that_does_not_hold_is_infeasible_and_names_the_fleet(tiny: Problem) -> None:
    with pytest.raises(Infeasible) as err:
        _decide(tiny, Fixed([1, 1, 1]), [-1, -1, -1])  # the first instance may not leave
    assert err.value.obj == "RobotFleet/f"


def test_operator_defaults_fill_only_what_the_fleet_left_out() -> None:
    given = SchedulerSettings(population=16)
    merged = with_defaults(given, {"population": 99, "generations": 7})
    assert merged.population == 16 and merged.generations == 7
    assert with_defaults(given, {}) is given


def test_a_gap_that_cannot_be_computed_leaves_the_plan_and_is_logged(
    tiny: Problem, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    assert _decide(tiny, CorePlanner(), [0, 0, 0]).gap is not None

    def broken(*_: object, **__: object) -> None:
        raise ValueError("a bug in the bound")

    monkeypatch.setattr("fogfleet.scheduling.decision.plan_gap", broken)
    decision = _decide(tiny, CorePlanner(), [0, 0, 0])
    assert decision.gap is None and (decision.placement >= 0).all()
    assert "gap could not be computed" in caplog.text and "a bug in the bound" in caplog.text
