from __future__ import annotations

import itertools

import numpy as np
import pytest

from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.exact import lp_bound, scalarised, solve_exact
from fogfleet.scheduling.objectives import constraints


def test_milp_equals_brute_force_on_tiny_fleet(tiny: Problem) -> None:
    best = np.inf
    for plan in itertools.product(
        *(np.flatnonzero(tiny.allowed[i]) for i in range(tiny.n_instances))
    ):
        x = np.array(plan)
        if np.all(constraints(tiny, x[None, :], tiny.limits) <= 1e-9):
            best = min(best, scalarised(tiny, x))
    res = solve_exact(tiny)
    assert res.value == pytest.approx(best, abs=1e-9)
    assert scalarised(tiny, res.placement) == pytest.approx(best, abs=1e-9)


def test_lp_relaxation_is_a_lower_bound(tiny: Problem) -> None:
    assert solve_exact(tiny, relax=True).value <= solve_exact(tiny).value + 1e-9


def test_lp_bound_by_interior_point_is_the_relaxation_optimum(tiny: Problem) -> None:
    # the tiny fleet: the warehouse's MILP costs 12 s of CPU, four times the unit tier's limit
    relaxed = solve_exact(tiny, relax=True).value
    assert lp_bound(tiny) == pytest.approx(relaxed, rel=1e-6)
    assert lp_bound(tiny) <= solve_exact(tiny).value + 1e-9


def test_exact_refuses_large_fleets(tiny: Problem) -> None:
    with pytest.raises(InvalidSpec, match="limited to 3"):
        solve_exact(tiny, max_pairs=3)


def test_milp_with_cost_equals_brute_force_on_tiny_fleet(tiny: Problem) -> None:
    from fogfleet.scheduling.exact import DEFAULT_WEIGHTS

    w = {**DEFAULT_WEIGHTS, "cost": 5.0}
    best = min(
        scalarised(tiny, np.array(x), w)
        for x in itertools.product(
            *(np.flatnonzero(tiny.allowed[i]) for i in range(tiny.n_instances))
        )
        if np.all(constraints(tiny, np.array(x)[None, :], tiny.limits) <= 1e-9)
    )
    res = solve_exact(tiny, w)
    assert scalarised(tiny, res.placement, w) == pytest.approx(best, abs=1e-9)


def _edge_or_paid_cloud() -> Problem:
    """One 1-core instance that meets its cycle on a 4-core edge or a 16-core cloud at 1 per
    core-hour: the cloud leaves the larger reserve, the edge costs nothing."""
    from .conftest import make_problem

    return make_problem(
        tiers=[0, 1, 2],
        cpu=[2.0, 4.0, 16.0],
        mem=[4.0, 8.0, 8.0],
        home=[0],
        allowed=[[False, True, True]],
        activation=[1.0],
        cycle=[1.0],
        request=[[1.0, 1.0, 1.0]],
        exe=[[0.1, 0.1, 0.1]],
        cost=[0.0, 0.0, 1.0],
    )


def test_the_exact_scheduler_weighs_cost_when_the_fleet_lists_it() -> None:
    """Issue 35: ``exact`` ignored cost. Listed (or weighted), cost is in its sum; the reason
    names the weights, not an internal constant."""
    from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
    from fogfleet.scheduling.solver import plan

    p = _edge_or_paid_cloud()
    plain = plan(p, SchedulerSettings(algorithm="exact"))
    assert plain.placement.tolist() == [2]  # a tie-break weight does not outweigh the reserve
    listed = SchedulerSettings(
        algorithm="exact", objectives=["missRate", "missedCycles", "onboard", "reserve", "cost"]
    )
    s = plan(p, listed)
    assert s.placement.tolist() == [1]
    assert "cost" in s.choice_reason and "DEFAULT_WEIGHTS" not in s.choice_reason
    weighted = SchedulerSettings(algorithm="exact", weights=[{"objective": "cost", "weight": 2}])
    assert plan(p, weighted).placement.tolist() == [1]
