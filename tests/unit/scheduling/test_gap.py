"""scheduling.gap: a plan's S against a lower bound on every plan's S (issue 46)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.configurations import robot_bound
from fogfleet.scheduling.exact import DEFAULT_WEIGHTS, lp_bound, solve_exact
from fogfleet.scheduling.gap import PlanGap, plan_gap

ROOT = Path(__file__).resolve().parents[3]


def test_the_optimum_is_within_the_solvers_tolerance_of_the_bound_and_a_worse_plan_is_not(
    tiny: Problem,
) -> None:
    optimum = solve_exact(tiny).placement
    best = plan_gap(tiny, optimum, DEFAULT_WEIGHTS)
    assert best is not None and best.kind in ("robot", "lp")
    assert best.bound <= best.value + 1e-9 and best.percent < 1.0
    worse = optimum.copy()
    worse[1:] = 0  # both free instances on board: more on-board use, a higher peak
    assert worse.tolist() != optimum.tolist()
    other = plan_gap(tiny, worse, DEFAULT_WEIGHTS)
    assert other is not None and other.bound == best.bound
    assert other.percent > best.percent + 1.0
    # with the optimum on the front, the best found is the optimum; the deployed stays worse
    both = plan_gap(tiny, worse, DEFAULT_WEIGHTS, np.stack([worse, optimum]))
    assert both is not None and both.value == pytest.approx(best.value)
    assert both.deployed_percent == pytest.approx(other.percent)
    assert other.percent > both.percent


def test_the_tighter_bound_is_reported() -> None:
    # three warehouse robots on two edges: the robot bound is above the LP's (test_exact)
    cat, fleet = synthetic_fleet(3, 2, 2)
    p = build_problem(fleet, cat)
    gap = plan_gap(p, solve_exact(p).placement, DEFAULT_WEIGHTS)
    whole = robot_bound(p)
    assert gap is not None and whole is not None and whole > lp_bound(p)
    assert gap.kind == "robot" and gap.bound == whole


def test_an_unplaced_instance_gets_no_gap(tiny: Problem) -> None:
    x = solve_exact(tiny).placement.copy()
    x[2] = -1
    assert plan_gap(tiny, x, DEFAULT_WEIGHTS) is None


@pytest.mark.parametrize(
    ("value", "bound", "percent"),
    [(1.1, 1.0, 10.0), (1.0, 1.0 + 1e-12, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, np.inf)],
)
def test_the_percent_is_above_the_bound_and_never_negative(value, bound, percent) -> None:
    gap = PlanGap(value, bound, "lp", value)
    assert gap.percent == pytest.approx(percent) and gap.deployed_percent == gap.percent


def test_a_fleet_of_shared_modules_only_gets_a_gap() -> None:
    # the demo's shared-detector fleet cut to its shared detector: no robot has an instance of
    # its own, so every robot has one configuration (nothing on board)
    cat = load_paths([ROOT / "manifests/examples/shared-detector"])
    fleet = cat.fleets[0]
    spec = fleet.spec.model_copy(
        update={"modules": [m for m in fleet.spec.modules if m.name == "object-detector"]}
    )
    p = build_problem(fleet.model_copy(update={"spec": spec}), cat)
    assert p.n_instances > 0 and (p.home < 0).all()
    optimum = solve_exact(p).placement
    gap = plan_gap(p, optimum, DEFAULT_WEIGHTS)
    whole = robot_bound(p)
    assert whole is not None and gap is not None
    assert whole <= gap.value + 1e-9 and gap.percent < 1.0
