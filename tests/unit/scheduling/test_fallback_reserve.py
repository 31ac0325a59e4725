"""The on-board reserve of modules with a fallback (issue 13): the robot holds the module's
on-board share wherever the module runs, in every part of the planner."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.evaluation import Evaluation
from fogfleet.scheduling.exact import solve_exact
from fogfleet.scheduling.heuristics import greedy
from fogfleet.scheduling.local import MoveEvaluator
from fogfleet.scheduling.objectives import constraints
from fogfleet.scheduling.operators import repair_plans
from fogfleet.scheduling.problem import PlacementProblem
from fogfleet.scheduling.solver import plan

from .conftest import make_problem

ROBOT, EDGE = 0, 1


def _robot_and_edge(pinned_cpu: float = 1.0) -> Problem:
    """A 2-core robot and a 4-core edge node. Instance 0 is pinned on board; instances 1 and
    2 (1 core each) may run on either: 1 as well on the edge (short transfer), 2 misses most
    cycles there (its 60 ms transfer + 50 ms work exceed its 100 ms cycle)."""
    return make_problem(
        tiers=[0, 1],
        cpu=[2.0, 4.0],
        mem=[4.0, 8.0],
        home=[0, 0, 0],
        allowed=[[True, False], [True, True], [True, True]],
        activation=[1.0, 1.0, 1.0],
        cycle=[0.1, 0.1, 0.1],
        request=[[pinned_cpu, 0.0], [1.0, 1.0], [1.0, 1.0]],
        exe=[[0.02, 0.0], [0.05, 0.05], [0.05, 0.05]],
        exe_std=[[0.002, 0.0], [0.01, 0.01], [0.01, 0.01]],
        net=[[0.0, 0.0], [0.0, 0.01], [0.0, 0.06]],
        memory=[1.0, 1.0, 1.0],
    )


def _with_fallback(p: Problem, *rows: int) -> Problem:
    keep = np.zeros(p.n_instances, dtype=bool)
    keep[list(rows)] = True
    return replace(p, fallback=keep)


def _robot_cpu(p: Problem, x: np.ndarray) -> float:
    return float(Evaluation(p, np.asarray(x)[None, :], p.limits).cpu_requested[0, ROBOT])


def test_the_robot_holds_the_share_of_an_offloaded_fallback() -> None:
    p = _with_fallback(_robot_and_edge(), 1)
    np.testing.assert_allclose(p.fallback_reserve(p.limits)[ROBOT], [1.0, 1.0, 0.0])
    np.testing.assert_allclose(p.fallback_reserve(p.limits)[EDGE], 0.0)
    # offloaded: pinned 1 + reserve 1; on board: the same two cores (no double count)
    assert _robot_cpu(p, [ROBOT, EDGE, EDGE]) == pytest.approx(2.0)
    assert _robot_cpu(p, [ROBOT, ROBOT, EDGE]) == pytest.approx(2.0)
    # a third core on the robot breaks its capacity only because of the reserve
    assert constraints(p, np.array([[ROBOT, EDGE, ROBOT]]), p.limits).max() > 0
    plain = _robot_and_edge()
    assert constraints(plain, np.array([[ROBOT, EDGE, ROBOT]]), plain.limits).max() <= 0


@pytest.mark.parametrize("style", ["best-fit", "spread", "level", "onboard"])
def test_greedy_leaves_the_reserve_free(style: str) -> None:
    p = _with_fallback(_robot_and_edge(), 1)
    x = greedy(p, p.limits, style)
    assert _robot_cpu(p, x) <= 2.0 + 1e-9, x


def test_the_planner_sends_the_other_module_to_the_edge() -> None:
    """Without the fallback, module 2 (which misses on the edge) gets the robot's free core;
    with it, the robot keeps that core for the fallback and module 2 has to go to the edge."""
    settings = SchedulerSettings(seed=1, generations=20, population=20)
    plain = _robot_and_edge()
    assert plan(plain, settings).placement[2] == ROBOT
    assert solve_exact(plain).placement[2] == ROBOT
    p = _with_fallback(_robot_and_edge(), 1)
    s = plan(p, settings)
    assert s.feasible
    assert s.placement[2] == EDGE and _robot_cpu(p, s.placement) <= 2.0 + 1e-9
    exact = solve_exact(p).placement
    assert exact[2] == EDGE and _robot_cpu(p, exact) <= 2.0 + 1e-9


def test_the_repair_moves_what_the_reserve_leaves_no_room_for() -> None:
    p = _with_fallback(_robot_and_edge(), 1)
    pp = PlacementProblem(p, ("missRate",), with_limits=True)
    x = repair_plans(pp, np.array([[ROBOT, EDGE, ROBOT]]))
    assert _robot_cpu(p, x[0]) <= 2.0 + 1e-9, x


def test_local_moves_count_the_reserve() -> None:
    """A move of the fallback itself never changes its robot's load; moving the other one
    on board is infeasible (the MoveEvaluator agrees with the whole evaluation)."""
    p = _with_fallback(_robot_and_edge(), 1)
    pp = PlacementProblem(p, ("missRate", "reserve"), with_limits=True)
    me = MoveEvaluator(pp)
    fulls = np.array([[ROBOT, EDGE, EDGE], [ROBOT, ROBOT, EDGE]])
    par, inst, node = me.moves(fulls, me.parents(fulls), 100)
    moves = set(zip(par.tolist(), inst.tolist(), node.tolist(), strict=True))
    assert (0, 1, ROBOT) in moves and (0, 2, ROBOT) not in moves
    assert (1, 1, EDGE) in moves and (1, 2, ROBOT) not in moves
    _, G = me.evaluate(fulls, par, inst, node)
    kids = me.children(fulls, par, inst, node)
    np.testing.assert_allclose(G, constraints(p, kids, p.limits), atol=1e-12)


def test_a_robot_too_small_for_the_reserve_makes_the_plan_infeasible() -> None:
    """1.5 pinned cores + the fallback's core exceed the 2-core robot wherever it runs."""
    settings = SchedulerSettings(seed=1, generations=10, population=12, allow_degraded=False)
    assert plan(_robot_and_edge(1.5), settings).feasible
    s = plan(_with_fallback(_robot_and_edge(1.5), 1), settings)
    assert not s.feasible


def test_what_a_lost_link_leaves_of_each_robot() -> None:
    from fogfleet.scheduling.fallback import disconnected

    p = _with_fallback(_robot_and_edge(), 1)
    (cut,) = disconnected(p, np.array([ROBOT, EDGE, EDGE]))
    assert (cut.robot, cut.reserved_cpu, cut.standbys, cut.stopped) == ("n0", 1.0, ("m1",), ("m2",))
    # on board the pinned module and the standby meet their 100 ms cycles; m2 is gone
    assert cut.miss_rate == pytest.approx(1 / 3, abs=1e-3)
    # nothing offloaded: nothing to lose
    assert disconnected(p, np.array([ROBOT, ROBOT, ROBOT])) == []


def test_onboard_does_not_count_the_cpu_a_standby_already_holds() -> None:
    """F1 (issue 35): module 1's standby holds its core on the robot whatever the plan, so
    running module 1 there adds nothing to on-board use; module 2 (no fallback) adds its own.
    The local search's incremental F1 and the exact solver's agree."""
    from fogfleet.scheduling.objectives import evaluate

    p = _with_fallback(_robot_and_edge(), 1)

    def f1(x: list[int]) -> float:
        return float(evaluate(p, np.array([x]), p.limits, ("onboard",))["onboard"][0])

    assert f1([ROBOT, ROBOT, EDGE]) == pytest.approx(f1([ROBOT, EDGE, EDGE]))
    assert f1([ROBOT, EDGE, ROBOT]) > f1([ROBOT, EDGE, EDGE]) + 0.4  # a whole core of 2
    pp = PlacementProblem(p, ("onboard", "missRate"), with_limits=True)
    me = MoveEvaluator(pp)
    fulls = np.array([[ROBOT, EDGE, EDGE], [ROBOT, ROBOT, EDGE]])
    par, inst, node = me.moves(fulls, me.parents(fulls), 100)
    vals, _ = me.evaluate(fulls, par, inst, node)
    kids = me.children(fulls, par, inst, node)
    np.testing.assert_allclose(vals["onboard"], evaluate(p, kids, p.limits)["onboard"])


def test_the_exact_optimum_counts_f1_as_the_evaluation_does() -> None:
    """The MILP's F1 term leaves out what a standby holds, as ``Evaluation.cpu_onboard``:
    its optimum is the brute-force minimum of ``scalarised``."""
    import itertools

    from fogfleet.scheduling.exact import scalarised

    p = _with_fallback(_robot_and_edge(), 1)
    best = min(
        scalarised(p, np.array(x))
        for x in itertools.product(*(np.flatnonzero(p.allowed[i]) for i in range(3)))
        if np.all(constraints(p, np.array(x)[None, :], p.limits) <= 1e-9)
    )
    assert scalarised(p, solve_exact(p).placement) == pytest.approx(best, abs=1e-9)
