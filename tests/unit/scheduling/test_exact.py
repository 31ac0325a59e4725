from __future__ import annotations

import itertools

import numpy as np
import pytest

from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.exact import scalarised, solve_exact
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


def test_exact_refuses_large_fleets(tiny: Problem) -> None:
    with pytest.raises(InvalidSpec, match="limited to 3"):
        solve_exact(tiny, max_pairs=3)
