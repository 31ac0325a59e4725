"""The stall rule that ends a converged evolution (scheduling/convergence.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.bench.scheduling import WAREHOUSE
from fogfleet.domain.build import build_problem
from fogfleet.scheduling.convergence import (
    MIN_WINDOW,
    WARM_WINDOW,
    StallWatch,
    improves,
    lexicographic_best,
    stall_window,
)
from fogfleet.scheduling.solver import plan


def F(*rows: tuple[float, ...]) -> np.ndarray:
    return np.array(rows, dtype=np.float64)


def test_the_lexicographic_best_is_smallest_in_the_first_objective_then_the_next() -> None:
    got = lexicographic_best(F((0.1, 0.0), (0.0, 5.0), (0.0, 2.0), (0.2, -1.0)))
    assert got.tolist() == [0.0, 2.0]


def test_an_improvement_is_decided_by_the_first_objective_that_differs() -> None:
    assert improves(np.array([0.0, 9.0]), np.array([0.1, 0.0]))
    assert not improves(np.array([0.1, 0.0]), np.array([0.0, 9.0]))
    assert improves(np.array([0.0, 1.0]), np.array([0.0, 2.0]))
    assert not improves(np.array([0.0, 2.0]), np.array([0.0, 2.0]))
    # float noise is not progress
    assert not improves(np.array([1.0 - 1e-12, 0.0]), np.array([1.0, 0.0]))


def test_the_default_window_grows_with_the_genes_and_a_setting_wins() -> None:
    assert stall_window(None, 40) == 10
    assert stall_window(None, 1000) == 100
    assert stall_window(25, 1000) == 25
    assert stall_window(0, 40) == 0


def test_the_watch_stops_after_a_window_without_improvement() -> None:
    watch = StallWatch(3)
    ok = np.zeros(2)
    assert not watch.update(F((1.0, 1.0), (2.0, 0.0)), ok)  # gen 1: first best
    assert not watch.update(F((0.5, 1.0), (2.0, 0.0)), ok)  # gen 2: better
    assert not watch.update(F((0.5, 1.0), (0.5, 2.0)), ok)  # gen 3: same best
    assert not watch.update(F((0.5, 1.0), (0.5, 2.0)), ok)  # gen 4
    assert watch.update(F((0.5, 1.0), (0.9, 0.0)), ok)  # gen 5: 3 without improvement
    assert watch.best is not None and watch.best.tolist() == [0.5, 1.0]


def test_infeasible_generations_never_count_as_stalled() -> None:
    watch = StallWatch(2)
    bad = np.ones(1)
    for _ in range(5):
        assert not watch.update(F((0.0, 0.0)), bad)
    assert not watch.update(F((0.0, 0.0)), np.zeros(1))  # first feasible plan
    assert not watch.update(F((0.0, 0.0)), np.zeros(1))
    assert watch.update(F((0.0, 0.0)), np.zeros(1))


def test_a_window_of_zero_never_stops() -> None:
    watch = StallWatch(0)
    for _ in range(50):
        assert not watch.update(F((0.0,)), np.zeros(1))


@pytest.fixture(scope="module")
def warehouse() -> tuple:
    catalog = load_paths([WAREHOUSE])
    fleet = catalog.fleets[0]
    return build_problem(fleet, catalog), fleet.spec.scheduler


def test_a_converged_warehouse_plan_stops_early_says_so_and_is_reproducible(warehouse) -> None:
    problem, settings = warehouse
    # a clock that stands still: convergence, never the time budget, may end this search,
    # however slow or loaded the machine
    first = plan(problem, settings, clock=lambda: 0.0)
    assert first.generations < settings.generations
    assert f"converged after {first.generations} generations" in first.choice_reason
    assert not first.time_budget_reached  # converged, not cut (issue 35)
    again = plan(problem, settings, clock=lambda: 0.0)
    assert again.generations == first.generations
    assert np.array_equal(np.asarray(again.placement), np.asarray(first.placement))


def test_stall_generations_zero_runs_every_generation(warehouse) -> None:
    problem, settings = warehouse
    small = settings.model_copy(update={"stall_generations": 0, "generations": 25})
    s = plan(problem, small)
    assert s.generations == 25
    assert "converged" not in s.choice_reason


def test_a_warm_start_stops_after_a_short_window_unless_the_fleet_sets_one() -> None:
    assert stall_window(None, 8000) == 800
    assert stall_window(None, 8000, warm=True) == WARM_WINDOW < MIN_WINDOW
    assert stall_window(25, 8000, warm=True) == 25
