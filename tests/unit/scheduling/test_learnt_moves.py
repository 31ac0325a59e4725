"""A re-plan on learnt profiles moves a running module only on evidence (issue 49).

One robot's module runs on an edge node and may run on a second, smaller one whose work is
slower but that it never ran on (no noise learnt there). The closed loop learns the module's
profile on the first edge (``domain.observed.correction``) and the migration-margin rule
(``decision.decide``) decides whether the re-plan moves it. Synthetic counts stand for the
bed's: a few misses in a few hundred warm-up cycles, against many cycles or a large error.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import norm

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.observed import Observation, Timing, correction
from fogfleet.domain.problem import Problem
from fogfleet.domain.rows import Learnt, ProfileRow
from fogfleet.scheduling.decision import Decision, decide, fingerprint

from .conftest import Fixed, make_problem

SETTINGS = SchedulerSettings(population=8, generations=4, seed=1, incremental=False)
CYCLE = 0.100
BIG = ProfileRow(0.5, 0.060, 0.004)  # the edge it runs on: 60 ms of work, 40 ms of slack
SMALL = ProfileRow(0.3, 0.070, 0.004)  # the small edge: slower, never measured
PRIOR = 100


def fleet(big: ProfileRow, small: ProfileRow, on: int) -> Problem:
    """Robot 0 (the module may not run there), edge 1 (big), edge 2 (small); it runs on ``on``."""
    problem = make_problem(
        tiers=[0, 1, 1],
        cpu=[1.0, 0.8, 0.3],
        mem=[4.0, 8.0, 8.0],
        home=[0],
        allowed=[[False, True, True]],
        activation=[1.0],
        cycle=[CYCLE],
        request=[[0.5, 0.5, 0.3]],
        exe=[[1.0, big.mean, small.mean]],
        exe_std=[[0.0, big.std, small.std]],
    )
    return dataclasses.replace(problem, current=np.array([on], dtype=np.int64))


def learnt(n: float, missed: float, mean: float = BIG.mean) -> Learnt:
    """What the loop learns on the big edge from ``n`` cycles, ``missed`` of them missed."""
    seen = Observation("m0", "big", BIG.cpu, n, mean, mean * 1.1, n, missed)
    got = correction([seen], {"big": [BIG]}, PRIOR, {"big": Timing(CYCLE)})
    return got["big"][0]


def replan(problem: Problem, to: int, last: Decision | None = None) -> Decision:
    fp = fingerprint(problem, SETTINGS)
    before = problem.current.copy()
    return decide(Fixed([to]), problem, SETTINGS, fleet="f", fp=fp, before=before, last=last)


def test_noise_learnt_from_a_few_hundred_warm_up_cycles_moves_nothing() -> None:
    # the bed's warm-up: 6 misses in 400 cycles (1.5 %), 60 ms of work in a 100 ms cycle
    got = learnt(400, 6)
    problem = fleet(got.row(BIG), SMALL, on=1)
    decision = replan(problem, to=2)
    assert decision.migrations == 0 and decision.placement[0] == 1, decision.choice_reason


def test_well_measured_noise_still_moves_the_module() -> None:
    # 3 % of 6000 cycles missed where the model predicts none: the small edge is better
    got = learnt(6000, 180)
    decision = replan(fleet(got.row(BIG), SMALL, on=1), to=2)
    assert decision.placement[0] == 2 and decision.migrations == 1, decision.choice_reason


def test_a_profile_four_times_too_optimistic_re_plans_at_once() -> None:
    """e2e/tests/test_closed_loop.py's case: 30 ms declared, 120 ms measured in a 100 ms cycle;
    nearly every cycle missed; two robots' 300 cycles each in its 30 s window, prior 100 (a
    third of them suffice too). The factor explains it, and it needs no minimum of cycles.
    Edge 1 stands for the robots it runs on, edge 2 for the edge it is declared 70 ms on."""
    declared = ProfileRow(0.1, 0.030, 0.003)
    edge = ProfileRow(0.1, 0.070, 0.010)
    for n in (600, 200):
        seen = Observation("m0", "robot", 0.1, n, 0.120, 0.130, n, 0.95 * n)
        timing = {"robot": Timing(CYCLE)}
        ((got, _),) = correction([seen], {"robot": [declared]}, 100, timing).values()
        assert got.factor > 2.9 and got.noise == 0.0
        decision = replan(fleet(got.row(declared), edge, on=1), to=2)
        assert decision.placement[0] == 2 and decision.migrations == 1, decision.choice_reason


def _misses(p: float) -> ProfileRow:
    """A row on the small edge whose one cycle misses with probability ``p``."""
    return ProfileRow(SMALL.cpu, SMALL.mean, (CYCLE - SMALL.mean) / float(norm.isf(p)))


def test_a_module_moved_for_noise_does_not_come_back_for_a_small_gain() -> None:
    noisy = learnt(6000, 180).row(BIG)
    there = replan(fleet(noisy, SMALL, on=1), to=2)
    assert there.placement[0] == 2
    # on the small edge it misses 0.65 % now; the big edge's estimate falls to 0.5 %: the
    # 0.15 points beat the margin (0.1) but not twice it
    big = ProfileRow(BIG.cpu, BIG.mean, (CYCLE - BIG.mean) / float(norm.isf(0.005)))
    back = replan(fleet(big, _misses(0.0065), on=2), to=1, last=there)
    assert back.placement[0] == 2 and back.migrations == 0, back.choice_reason
    # the same gain moves a module that never ran on the big edge
    fresh = replan(fleet(big, _misses(0.0065), on=2), to=1)
    assert fresh.placement[0] == 1 and fresh.migrations == 1
    assert "twice the margin" in back.choice_reason
    assert there.left == {"n0/m0": "n1"} and back.left == there.left  # still remembered


def test_a_return_worth_twice_the_margin_is_made() -> None:
    there = replan(fleet(learnt(6000, 180).row(BIG), SMALL, on=1), to=2)
    big = ProfileRow(BIG.cpu, BIG.mean, (CYCLE - BIG.mean) / float(norm.isf(0.005)))
    back = replan(fleet(big, _misses(0.008), on=2), to=1, last=there)  # 0.3 points
    assert back.placement[0] == 1 and back.migrations == 1, back.choice_reason
    assert back.left == {"n0/m0": "n2"}  # and leaving again needs twice the margin
