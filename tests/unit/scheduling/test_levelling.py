"""Peak levelling (``scheduling.levelling``): plans with a lower peak, never worse in misses."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling import solver
from fogfleet.scheduling.heuristics import Fit, greedy
from fogfleet.scheduling.levelling import (
    MISS_TOLERANCE,
    Work,
    level,
    levelled_plans,
    with_levelled,
)
from fogfleet.scheduling.objectives import evaluate
from fogfleet.scheduling.problem import PlacementProblem
from fogfleet.scheduling.stickiness import feasible

NAMES = ("missRate", "missedCycles", "onboard", "reserve", "balance")


@lru_cache(maxsize=1)
def _fleet() -> Problem:
    """20 robots x 8 modules on 8 edges: a spread plan fills some node to 100 %."""
    catalog, fleet = synthetic_fleet(20, 8, 1)
    return build_problem(fleet, catalog)


def _peak(p: Problem, x: np.ndarray) -> float:
    return float(evaluate(p, x[None, :], p.limits, ("reserve",))["reserve"][0])


def _start(p: Problem) -> tuple[Fit, np.ndarray]:
    fit = Fit(p, p.limits)
    x = greedy(p, p.limits, "spread", fit)
    assert _peak(p, x) == pytest.approx(1.0)
    return fit, x


@pytest.mark.parametrize("target", [0.97, 0.93])
def test_a_levelled_plan_is_feasible_under_its_target_and_misses_no_more(target: float) -> None:
    p = _fleet()
    fit, x = _start(p)
    y = level(fit, x, target)
    assert y is not None
    assert feasible(p, y, True)
    assert _peak(p, y) <= target + 1e-9
    rows = np.arange(p.n_instances)
    assert np.all(fit.q[rows, y] <= fit.q[rows, x] + MISS_TOLERANCE)
    pinned = p.allowed.sum(axis=1) == 1
    assert np.array_equal(y[pinned], x[pinned])


def test_a_target_below_what_cannot_move_is_refused() -> None:
    p = _fleet()
    fit, x = _start(p)
    assert level(fit, x, 0.2) is None


def test_the_ladder_finds_plans_down_to_a_lower_peak_and_stops_without_work() -> None:
    p = _fleet()
    fit, x = _start(p)
    plans = levelled_plans(fit, x)
    peaks = [_peak(p, y) for y in plans]
    assert plans and min(peaks) < 0.95
    assert all(feasible(p, y, True) for y in plans)
    assert levelled_plans(fit, x, work=Work(0)) == []


def test_nothing_is_added_without_the_reserve_objective() -> None:
    p = _fleet()
    _, x = _start(p)
    pp = PlacementProblem(p, ("missRate", "onboard"))
    X = x[pp.genes][None, :]
    F = pp.objectives_of(X)
    X2, F2 = with_levelled(pp, X, F)
    assert X2 is X and F2 is F


@pytest.mark.integration
def test_nsga2_reaches_a_lower_peak_with_levelling_than_without(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    p = _fleet()
    settings = SchedulerSettings(seed=1, objectives=list(NAMES))
    k = NAMES.index("reserve")
    with_it = solver.nsga2(p, settings)
    monkeypatch.setattr(solver, "with_levelled", lambda pp, X, F, stop=None: (X, F))
    without = solver.nsga2(p, settings)
    assert with_it.pareto_front is not None and without.pareto_front is not None
    assert with_it.pareto_front[:, k].min() < without.pareto_front[:, k].min() - 0.01
