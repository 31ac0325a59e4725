"""A re-plan on learnt profiles moves a running module only on evidence (issue 49).

One robot's module runs on an edge node and may run on a second, smaller one whose work is
slower but that it never ran on (no noise learnt there). The closed loop learns the module's
profile on the first edge (``domain.observed.correction``) and the migration-margin rule
(``decision.decide``) decides whether the re-plan moves it. Synthetic counts stand for the
bed's: a few misses in a few hundred warm-up cycles, against many cycles or a large error.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from scipy.stats import norm

from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerSettings
from fogfleet.domain.build import build_problem
from fogfleet.domain.observed import Observation, Timing, correction
from fogfleet.domain.problem import Problem
from fogfleet.domain.rows import Learnt, ProfileRow
from fogfleet.scheduling.decision import Decision, decide, fingerprint
from fogfleet.scheduling.objectives import objective_values

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


# -- a node the module never ran on is no quieter than the one it runs on (issue 49) ----------
#
# The paper bed's pose estimator: 60 +- 6 ms of work at 267m in a 100 ms cycle, on two edges
# of different hardware types that run the same i9 rows (e2e/bench/real/paper). The truth of
# the synthetic cycles below: every cycle is its work plus a normal noise of 13 ms (what the
# bed's loop learnt), on either edge alike; so no move between them gains anything.

TRUE_NOISE = 0.013
POSE = "pose"


def _node(name: str, hw: str, cpu: str, tier: str = "edge") -> dict[str, Any]:
    spec: dict[str, Any] = {"tier": tier, "hardwareType": hw, "capacity": {"cpu": cpu}}
    spec["capacity"]["memory"] = "2Gi"
    spec["network"] = [{"type": "lan", "latencyMillis": 1, "bandwidthMbps": 1000}]
    return {"apiVersion": "fogfleet.io/v1alpha1", "kind": "ComputeNode",
            "metadata": {"name": name}, "spec": spec}  # fmt: skip


def bed(
    edge2_rows: list[dict[str, Any]] | None = None, robots: int = 1
) -> tuple[RobotFleet, Catalog]:
    """``robots`` robots, ``edge-1`` (i9-13900, 800m) and ``edge-2`` (i9-9900, 300m); the pose
    estimator may run on the edges only. ``edge2_rows``: rows of its own for edge-2's type."""
    rows = [
        {"hardwareType": "default", "cpu": cpu, "meanMillis": mean, "stdMillis": std}
        for cpu, mean, std in (("133m", 100, 10), ("267m", 60, 6), ("533m", 45, 5))
    ]
    module = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "SoftwareModule",
        "metadata": {"name": POSE, "namespace": "t"},
        "spec": {
            "template": {"image": "example.org/pose:1"},
            "taxonomy": {
                "executionPattern": "continuous",
                "realtime": "soft",
                "safety": "relevant",
            },
            "cycleTimeMillis": 100,
            "resources": {"cpu": "33m", "memory": "128Mi"},
            "requirements": {"tiers": ["edge"]},
            "profile": rows + (edge2_rows or []),
        },
    }
    fleet = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "RobotFleet",
        "metadata": {"name": "f", "namespace": "t"},
        "spec": {
            "robots": [f"robot-{k}" for k in range(robots)],
            "nodes": ["edge-1", "edge-2"],
            "modules": [{"name": POSE}],
        },
    }
    catalog = Catalog()
    for doc in (
        *(_node(f"robot-{k}", "pi4", "1", "robot") for k in range(robots)),
        _node("edge-1", "i9-13900", "800m"),
        _node("edge-2", "i9-9900", "300m"),
        module,
        fleet,
    ):
        catalog.add(parse_object(doc))
    (got,) = catalog.fleets
    return got, catalog


def warm_up(n: int, seed: int) -> Observation:
    """``n`` synthetic cycles of the pose estimator at 267m on edge-1: work N(60, 6) ms plus the
    true noise; a cycle over 100 ms misses."""
    rng = np.random.default_rng(seed)
    work = rng.normal(0.060, 0.006, n)
    missed = float(np.count_nonzero(work + rng.normal(0.0, TRUE_NOISE, n) > CYCLE))
    p95 = float(np.quantile(work, 0.95))
    return Observation(POSE, "i9-13900", 0.267, n, float(work.mean()), p95, n, missed)


def on_bed(corrections: dict[tuple[str, str], Learnt], on: str, **kw: Any) -> Problem:
    fleet, catalog = bed(**kw)
    problem = build_problem(fleet, catalog, corrections=corrections)
    j = next(j for j, n in enumerate(problem.nodes) if n.name == on)
    return dataclasses.replace(problem, current=np.full(problem.n_instances, j, dtype=np.int64))


def node_index(problem: Problem, name: str) -> int:
    return next(j for j, n in enumerate(problem.nodes) if n.name == name)


def test_noise_learnt_on_the_edge_it_runs_on_never_moves_it_to_one_it_never_ran_on() -> None:
    """Today's rule before issue 49's fix took the noise as none on the edge the module never
    ran on: from 1000 cycles on (two pose instances' warm-up) it learnt 11-12 ms on edge-1,
    predicted about 0.1 % missed there against none on edge-2, and moved it, to miss as much
    (on the bed: more). The noise is the module's on either edge; a move gains nothing."""
    declared = {"i9-13900": [ProfileRow(0.267, 0.060, 0.006)]}
    learnt_any = False
    for n in (600, 1200, 3000, 6000):
        for seed in (1, 2, 3):
            seen = warm_up(n, seed)
            got = correction([seen], declared, PRIOR, {"i9-13900": Timing(CYCLE)})
            learnt, _ = got["i9-13900"]
            learnt_any = learnt_any or learnt.noise > 0.005
            problem = on_bed({(POSE, "i9-13900"): learnt}, on="edge-1")
            decision = replan(problem, to=node_index(problem, "edge-2"))
            assert decision.migrations == 0, (n, seed, learnt, decision.choice_reason)
            assert decision.placement[0] == node_index(problem, "edge-1")
    assert learnt_any  # the loop did learn a noise: it is the move that was refused


def test_a_faster_node_still_wins_with_the_noise_carried_there() -> None:
    # edge-2's type runs the module in 40 ms at 267m: with the same 13 ms noise it misses
    # far less than edge-1 (60 ms), so the move gains beyond the noise and is made
    faster = [{"hardwareType": "i9-9900", "cpu": "267m", "meanMillis": 40, "stdMillis": 4}]
    learnt = Learnt(1.0, TRUE_NOISE)  # a fitted noise (noise_cycles unsaid)
    problem = on_bed({(POSE, "i9-13900"): learnt}, on="edge-1", edge2_rows=faster)
    edge2 = node_index(problem, "edge-2")
    assert problem.limits.exe_std[0, edge2] == pytest.approx(np.hypot(0.004, TRUE_NOISE))
    decision = replan(problem, to=edge2)
    assert decision.placement[0] == edge2 and decision.migrations == 1, decision.choice_reason


def test_a_node_the_module_ran_quietly_on_keeps_its_own_noise() -> None:
    # 3000 cycles on edge-2 without a miss: its noise is known to be none there, so the
    # noise learnt on edge-1 is not carried over and the move is made on evidence
    corrections = {
        (POSE, "i9-13900"): Learnt(1.0, TRUE_NOISE, 6000),
        (POSE, "i9-9900"): Learnt(1.0, 0.0, 3000),
    }
    problem = on_bed(corrections, on="edge-1")
    edge2 = node_index(problem, "edge-2")
    assert problem.limits.exe_std[0, edge2] == pytest.approx(0.006)
    decision = replan(problem, to=edge2)
    assert decision.placement[0] == edge2 and decision.migrations == 1, decision.choice_reason
    # a few hundred cycles there fitted no noise: not known, the learnt one stands in
    corrections[(POSE, "i9-9900")] = Learnt(1.0, 0.0, 0.0)
    problem = on_bed(corrections, on="edge-1")
    assert problem.limits.exe_std[0, edge2] == pytest.approx(np.hypot(0.006, TRUE_NOISE))
    assert replan(problem, to=edge2).migrations == 0


def test_a_learnt_profile_asking_for_more_cpu_holds_what_runs_instead_of_moving_it() -> None:
    """The bed's own failure (issue 49): two pose estimators on edge-1 at 267m; 15 ms of noise
    learnt there puts 267m's mean + 2 std past 90 % of the cycle, so the planner's row there
    becomes 533m and the two no longer fit edge-1's 800m. Before: no current placement to
    keep, so one moved to edge-2 "to make room" without a gain to beat, here even to a node
    the model itself predicts worse (70 ms of work there). Now what runs is held (267m
    requested, 533m its limit) unless the move gains by the margin."""
    slower = [{"hardwareType": "i9-9900", "cpu": "267m", "meanMillis": 70, "stdMillis": 4}]
    fleet, catalog = bed(edge2_rows=slower, robots=2)
    plain = build_problem(fleet, catalog)
    e1, e2 = node_index(plain, "edge-1"), node_index(plain, "edge-2")
    plain = dataclasses.replace(plain, current=np.full(2, e1, dtype=np.int64))
    first = decide(
        Fixed([e1, e1]), plain, SETTINGS, fleet="f", fp=fingerprint(plain, SETTINGS),
        before=plain.current,
    )  # fmt: skip
    assert first.placement.tolist() == [e1, e1] and not first.schedule.degraded
    learnt = {(POSE, "i9-13900"): Learnt(1.0, 0.015)}  # a fitted noise
    noisy = build_problem(fleet, catalog, corrections=learnt)
    noisy = dataclasses.replace(noisy, current=first.placement.copy())
    assert noisy.limits.cpu_request[0, e1] == pytest.approx(0.533)  # it asks for more there
    fp = fingerprint(noisy, SETTINGS)
    again = decide(
        Fixed([e1, e2]), noisy, SETTINGS, fleet="f", fp=fp, before=first.placement,
        last=first, last_problem=plain,
    )  # fmt: skip
    assert again.migrations == 0 and again.placement.tolist() == [e1, e1], again.choice_reason
    assert "kept running modules in place" in again.choice_reason
    moved = noisy.with_levels(None)
    worse = objective_values(moved, np.array([e1, e2]), True, ["missRate"])["missRate"]
    assert again.objectives["missRate"] < worse  # the move would have missed more
    # held with the fewest rungs that fit: one requests 267m, as it ran, the other 533m
    assert again.schedule.levels is not None and again.schedule.levels.tolist() == [1, 0]
    held = noisy.with_levels(again.schedule.levels)
    assert held.limits.cpu_request[:, e1].tolist() == pytest.approx([0.267, 0.533])
    # without a last decision (a first plan) nothing is held: the plan is what it proposes
    fresh = decide(Fixed([e1, e2]), noisy, SETTINGS, fleet="f", fp=fp, before=first.placement)
    assert fresh.migrations == 1
