"""A re-plan moves only what pays for itself: the migration-margin rule judges a whole plan,
and ``stickiness.trim_moves`` leaves out each move of it that gains less than the margin.

Two robots' modules run on a shared edge. Robot 0's misses every cycle there (its work takes
twice its cycle on the edge), robot 1's misses none anywhere. A plan that puts both on board
beats what runs by far, all of it from robot 0's move; robot 1's move rode along (the e2e
fallback test saw the GA move the healthy robot's detector with the degraded robot's).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.decision import decide, fingerprint
from fogfleet.scheduling.stickiness import trim_moves

from .conftest import Fixed, make_problem

SETTINGS = SchedulerSettings(population=8, generations=4, seed=1, incremental=False)
ROBOT_0, ROBOT_1, EDGE = 0, 1, 2


def two_robots_on_the_edge() -> Problem:
    problem = make_problem(
        tiers=[0, 0, 1],
        cpu=[1.0, 1.0, 2.0],
        mem=[4.0, 4.0, 8.0],
        home=[ROBOT_0, ROBOT_1],
        allowed=[[True, False, True], [False, True, True]],
        activation=[1.0, 1.0],
        cycle=[0.100, 0.100],
        request=[[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]],
        exe=[[0.040, 1.0, 0.200], [1.0, 0.040, 0.040]],
        exe_std=[[0.004, 0.0, 0.004], [0.0, 0.004, 0.004]],
    )
    return dataclasses.replace(problem, current=np.array([EDGE, EDGE], dtype=np.int64))


def test_a_move_that_gains_nothing_rides_no_longer_on_one_that_does() -> None:
    problem = two_robots_on_the_edge()
    fp = fingerprint(problem, SETTINGS)
    both_on_board = Fixed([ROBOT_0, ROBOT_1])
    decision = decide(both_on_board, problem, SETTINGS, fleet="f", fp=fp, before=problem.current)
    assert decision.placement.tolist() == [ROBOT_0, EDGE]
    assert decision.migrations == 1


def test_moves_the_fleet_needs_all_stay() -> None:
    problem = two_robots_on_the_edge()
    usable = np.ones(2, dtype=bool)
    only_the_needed = np.array([ROBOT_0, EDGE], dtype=np.int64)
    kept = trim_moves(problem, only_the_needed, usable, ["missRate"], 0.05)
    assert kept.tolist() == [ROBOT_0, EDGE]
    nothing_moves = trim_moves(problem, problem.current, usable, ["missRate"], 0.05)
    assert nothing_moves.tolist() == [EDGE, EDGE]
