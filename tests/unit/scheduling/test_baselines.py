from __future__ import annotations

import numpy as np

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.baselines import k8s_default, k8s_scores, onboard_plan, random_plan

from .conftest import make_problem

GI = 2.0**30


def _two_edges() -> Problem:
    # robot n0 (hosts nothing), A = n1: 4 cores / 4 GiB, B = n2: 8 cores / 2 GiB;
    # three 1-core, 1-GiB pods that may run on A or B
    return make_problem(
        tiers=[0, 1, 1],
        cpu=[2.0, 4.0, 8.0],
        mem=[GI, 4 * GI, 2 * GI],
        home=[-1, -1, -1],
        allowed=[[False, True, True]] * 3,
        activation=[1.0] * 3,
        cycle=[1.0] * 3,
        request=[[0.0, 1.0, 1.0]] * 3,
        exe=[[0.0, 0.1, 0.1]] * 3,
        memory=[GI] * 3,
    )


def test_k8s_scores_match_least_allocated_plus_balanced_allocation() -> None:
    cap_cpu = np.array([4000, 8000])
    cap_mem = np.array([4 * 2**30, 2 * 2**30])
    s = k8s_scores(cap_cpu, cap_mem, np.array([1000, 1000]), np.array([2**30, 2**30]))
    # A: least (75 + 75) / 2 = 75, balanced 100 -> 175
    # B: least (87 + 50) // 2 = 68, balanced int((1 - |0.125 - 0.5| / 2) * 100) = 81 -> 149
    assert s.tolist() == [175, 149]


def test_k8s_default_fills_the_balanced_node_until_the_other_scores_higher() -> None:
    s = k8s_default(_two_edges(), seed=1)
    # pod 1: A 175 > B 149; pod 2: A (50 + 50) / 2 + 100 = 150 > 149; pod 3: A 125 < B 149
    assert s.placement.tolist() == [1, 1, 2]
    assert s.with_limits is False and s.feasible


def test_k8s_default_places_the_pods_in_the_order_they_reach_the_scheduler() -> None:
    p = _two_edges()
    assert k8s_default(p, seed=1, order=np.array([0, 1, 2])).placement.tolist() == [1, 1, 2]
    # the same scoring with pod 2 first: pods 2 and 0 fill A, the last one goes to B
    assert k8s_default(p, seed=1, order=np.array([2, 0, 1])).placement.tolist() == [1, 2, 1]


def test_k8s_default_leaves_pods_pending_when_nothing_fits() -> None:
    p = _two_edges()
    from dataclasses import replace

    big = replace(p.nominal, cpu_request=np.full((3, 3), 5.0))
    s = k8s_default(replace(p, nominal=big), seed=1)
    assert s.placement.tolist() == [2, -1, -1]
    assert not s.feasible
    assert "Insufficient" in s.reasons[1]


def test_onboard_puts_robot_modules_home(warehouse: Problem) -> None:
    s = onboard_plan(warehouse)
    assert np.array_equal(s.placement, warehouse.home)
    assert set(s.objectives) == {
        "onboard",
        "reserve",
        "balance",
        "missedCycles",
        "missRate",
        "cost",
        "energy",
        "migrations",
    }


def test_random_plan_is_repaired_and_seeded(warehouse: Problem) -> None:
    a, b = random_plan(warehouse, seed=3), random_plan(warehouse, seed=3)
    assert a.feasible
    assert np.array_equal(a.placement, b.placement)
