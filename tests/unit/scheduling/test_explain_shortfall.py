"""The sentences that say why a fleet cannot be placed (scheduling.explain.shortfall): what a
person can act on, in their words (issue 35: no internal names, the fleet's shortfall, not one
node)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.explain.shortfall import infeasible_message

from .conftest import make_problem


def _three_gpu_modules_two_gpus() -> Problem:
    """Three instances that need a GPU each; two edge nodes with one GPU each."""
    p = make_problem(
        tiers=[0, 1, 1],
        cpu=[2.0, 8.0, 8.0],
        mem=[4.0, 8.0, 8.0],
        home=[0, 0, 0],
        allowed=[[False, True, True]] * 3,
        activation=[1.0] * 3,
        cycle=[1.0] * 3,
        request=[[1.0] * 3] * 3,
        exe=[[0.1] * 3] * 3,
    )
    cap = p.capacity.copy()
    cap[1:, 2] = 1.0
    return replace(p, capacity=cap, gpu=np.ones(3))


def test_a_gpu_shortage_names_the_fleets_shortfall_not_one_node() -> None:
    p = _three_gpu_modules_two_gpus()
    msg = infeasible_message(p, np.array([1, 1, 2]), {})
    assert "the fleet needs 3 GPUs in all" in msg and "have 2 (n1 1, n2 1): 1 GPU(s) short" in msg
    assert "over by" not in msg  # not "gpu:n1 over by 100%": the excess could go anywhere


def test_a_module_on_a_node_it_may_not_use_is_said_in_words() -> None:
    p = make_problem(
        tiers=[0, 1],
        cpu=[2.0, 4.0],
        mem=[4.0, 8.0],
        home=[0],
        allowed=[[False, True]],
        activation=[1.0],
        cycle=[1.0],
        request=[[1.0, 1.0]],
        exe=[[0.1, 0.1]],
    )
    msg = infeasible_message(p, np.array([0]), {})
    assert "geneSpace" not in msg
    assert "1 instance(s) on a node their module may not use" in msg
