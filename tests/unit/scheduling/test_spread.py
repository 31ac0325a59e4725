"""Shared services survive a node (issue 35 item 3): a shared module's replicas go to two
nodes whenever two allowed nodes exist (``scheduling.spread``), and the plan says so."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Instance, Problem
from fogfleet.scheduling.heuristics import Fit
from fogfleet.scheduling.solver import plan
from fogfleet.scheduling.spread import spread_groups, spread_plans, stacked

from .conftest import make_problem

FAST = {"population": 12, "generations": 6}


def shared_pair(edges: list[bool]) -> Problem:
    """A robot (node 0) with one on-board module, two edge nodes (1: faster, so both replicas
    would rather sit there) and a shared module ``det`` of two replicas allowed on ``edges``."""
    p = make_problem(
        tiers=[0, 1, 1],
        cpu=[2.0, 4.0, 4.0],
        mem=[4.0, 8.0, 8.0],
        home=[0, -1, -1],
        allowed=[[True, False, False], [False, *edges], [False, *edges]],
        activation=[1.0, 1.0, 1.0],
        cycle=[0.1, 0.1, 0.1],
        request=[[0.5, 0, 0], [0, 1.0, 1.0], [0, 1.0, 1.0]],
        exe=[[0.01, 0, 0], [0, 0.02, 0.06], [0, 0.02, 0.06]],
        exe_std=[[0.0, 0, 0], [0, 0.01, 0.02], [0, 0.01, 0.02]],
        cost=[0.0, 0.0, 0.1],
    )
    instances = (p.instances[0], Instance("", "det", 0), Instance("", "det", 1))
    return dataclasses.replace(p, instances=instances)


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_two_replicas_with_two_allowed_nodes_never_share_one(seed):
    problem = shared_pair([True, True])
    s = plan(problem, SchedulerSettings(seed=seed, **FAST))
    assert s.feasible
    assert int(s.placement[1]) != int(s.placement[2])
    assert "spread over 2+ nodes: det" in s.choice_reason


def test_a_single_allowed_node_still_takes_both_replicas():
    problem = shared_pair([True, False])
    s = plan(problem, SchedulerSettings(seed=1, **FAST))
    assert s.feasible
    assert list(s.placement[1:]) == [1, 1]
    assert "spread" not in s.choice_reason


def test_the_repair_moves_one_replica_to_the_other_node_with_room():
    problem = shared_pair([True, True])
    x = np.array([[0, 1, 1], [0, 2, 2], [0, 1, 2]], dtype=np.int64)
    assert stacked(problem, x)[:, 0].tolist() == [True, True, False]
    out = spread_plans(problem, x.copy(), Fit(problem, problem.limits))
    assert not stacked(problem, out).any()
    assert out[2].tolist() == [0, 1, 2]  # a plan already spread is left alone


def test_a_full_second_node_leaves_the_replicas_together():
    problem = shared_pair([True, True])
    full = dataclasses.replace(problem, capacity=problem.capacity * np.array([[1], [1], [0.1]]))
    x = np.array([[0, 1, 1]], dtype=np.int64)
    assert spread_plans(full, x.copy(), Fit(full, full.limits)).tolist() == [[0, 1, 1]]


def test_per_robot_modules_are_not_bound(tiny):
    assert spread_groups(tiny) == []


def test_an_incremental_re_plan_that_would_stack_the_replicas_asks_for_a_whole_plan():
    """Both replicas run on edge 1 (from before the rule); a change to one of the robot's 12
    modules re-plans incrementally: the stacked replicas make it ask for the whole fleet."""
    from fogfleet.scheduling.incremental import replan

    n = 12  # on-board modules: one changed is under the incremental path's 10 %
    p = make_problem(
        tiers=[0, 1, 1],
        cpu=[4.0, 4.0, 4.0],
        mem=[8.0, 8.0, 8.0],
        home=[0] * n + [-1, -1],
        allowed=[[True, False, False]] * n + [[False, True, True]] * 2,
        activation=[1.0] * (n + 2),
        cycle=[0.1] * (n + 2),
        request=[[0.1, 0, 0]] * n + [[0, 1.0, 1.0]] * 2,
        exe=[[0.01, 0, 0]] * n + [[0, 0.02, 0.06]] * 2,
    )
    instances = (*p.instances[:n], Instance("", "det", 0), Instance("", "det", 1))
    current = np.array([0] * n + [1, 1], dtype=np.int64)
    problem = dataclasses.replace(p, instances=instances, current=current)
    out = replan(problem, SchedulerSettings(seed=1, **FAST), changed=[0])
    assert out.schedule is None
    assert "stacks a shared module's replicas" in out.reason
