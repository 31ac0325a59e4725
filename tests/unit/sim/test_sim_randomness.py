"""Activation episodes, seeding, the sharing rule and the engine's two paths agreeing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray
from simkit import Job, build

from fogfleet.domain.problem import Problem
from fogfleet.sim import compare, simulate
from fogfleet.sim.engine import Track, run_independent, run_shared, water_fill
from fogfleet.sim.episodes import MAX_ACTIVE_S, MIN_ACTIVE_S, mean_episode_s, sample_episodes


@pytest.mark.parametrize("activation", [0.08, 0.3, 0.7])
def test_long_run_active_fraction_matches_the_activation(activation: float) -> None:
    jobs = [Job(f"m{k}", exe=0.1, cpu=1, cycle=0.5, activation=activation) for k in range(4)]
    p = build([64], jobs)
    r = simulate(p, np.zeros(4, dtype=np.int64), p.limits, duration_s=10_000.0, seed=3)
    assert float(np.mean(r.active_fraction)) == pytest.approx(activation, abs=0.03)
    # cycles run only while active: about activation * horizon / cycle per instance (a bit
    # more: each on-episode starts with a fresh cycle)
    expected = float(np.mean(r.active_fraction)) * 10_000.0 / 0.5
    assert float(np.mean(r.instance_cycles)) == pytest.approx(expected, rel=0.05)


def test_episode_lengths_are_task_like() -> None:
    on, off = mean_episode_s(0.7)
    assert MIN_ACTIVE_S <= on <= MAX_ACTIVE_S
    assert on / (on + off) == pytest.approx(0.7)
    on, off = mean_episode_s(0.08)
    assert on == MIN_ACTIVE_S and on / (on + off) == pytest.approx(0.08)
    assert sample_episodes(1.0, 100.0, np.random.default_rng(0)) == ([0.0], [math.inf])
    assert sample_episodes(0.0, 100.0, np.random.default_rng(0)) == ([], [])


def test_robots_are_active_independently() -> None:
    jobs = [Job("m", exe=0.1, cpu=1, cycle=1.0, activation=0.5, robot=f"r{k}") for k in range(2)]
    p = build([8], jobs)
    r = simulate(p, np.zeros(2, dtype=np.int64), p.limits, duration_s=600.0, seed=1)
    assert r.active_fraction[0] != r.active_fraction[1]


def _noisy_problem() -> tuple[Problem, NDArray[np.int64]]:
    jobs = [
        Job("a", exe=0.05, cpu=2, cycle=0.1, activation=0.6, std=0.02, net=0.01, net_std=0.004),
        Job("b", exe=0.08, cpu=2, cycle=0.1, activation=0.6, std=0.03),
        Job("c", exe=0.3, cpu=1, cycle=0.5, activation=0.3, std=0.1),
    ]
    return build([3], jobs), np.zeros(3, dtype=np.int64)


def test_same_seed_same_result_other_seed_other_result() -> None:
    p, placement = _noisy_problem()
    one = simulate(p, placement, p.limits, duration_s=60.0, seed=7)
    two = simulate(p, placement, p.limits, duration_s=60.0, seed=7)
    other = simulate(p, placement, p.limits, duration_s=60.0, seed=8)
    assert one.to_dict() == two.to_dict()
    assert one.to_dict() != other.to_dict()
    assert 0.0 < one.miss_rate < 1.0


def test_water_filling_caps_each_share_at_its_demand() -> None:
    assert water_fill([1.0, 1.0], 8.0) == [1.0, 1.0]
    assert water_fill([2.0, 2.0], 2.0) == [1.0, 1.0]
    assert water_fill([1.0, 4.0], 4.0) == [1.0, 3.0]
    assert water_fill([4.0, 0.5, 4.0], 3.0) == [1.25, 0.5, 1.25]
    assert water_fill([8.0], 6.0) == [6.0]


def test_weighted_water_filling_follows_the_weights_until_a_demand_caps_a_share() -> None:
    # CFS: a busy node's CPU goes by cpu.shares (the requests), never beyond what a job demands
    assert water_fill([1.0, 1.0], 1.0, [1.0, 3.0]) == pytest.approx([0.25, 0.75])
    assert water_fill([0.1, 1.0, 1.0], 1.0, [2.0, 1.0, 1.0]) == pytest.approx([0.1, 0.45, 0.45])
    assert water_fill([2.0, 2.0], 1.0, [1.0, 1.0]) == water_fill([2.0, 2.0], 1.0)
    assert water_fill([0.5, 0.5], 4.0, [1.0, 9.0]) == [0.5, 0.5]  # it fits: no sharing


def _track(rng: np.random.Generator, demand: float) -> Track:
    n = 400
    return Track(
        cycle=0.1,
        demand=demand,
        work=rng.uniform(0.01, 0.09, n).tolist(),
        d_in=rng.uniform(0.0, 0.01, n).tolist(),
        d_out=rng.uniform(0.0, 0.01, n).tolist(),
        episodes=([0.0, 12.0], [7.5, math.inf]),
        horizon=30.0,
    )


def test_event_loop_matches_the_independent_path_without_contention() -> None:
    rng = np.random.default_rng(0)
    a = [_track(rng, 1.0), _track(rng, 2.0)]
    rng = np.random.default_rng(0)
    b = [_track(rng, 1.0), _track(rng, 2.0)]
    busy_a = sum(run_independent(t) for t in a)
    busy_b = run_shared(b, 3.0, 30.0)
    assert busy_a == pytest.approx(busy_b)
    for ta, tb in zip(a, b, strict=True):
        assert ta.durations == pytest.approx(tb.durations)
        assert ta.missed == tb.missed


def test_no_cycle_starts_while_inactive() -> None:
    tr = _track(np.random.default_rng(1), 1.0)
    starts: list[float] = []
    t = tr.first_arrival()
    while t < math.inf:
        starts.append(tr.start)
        t = tr.complete(t + tr.work[tr.n])
    assert starts and all(s < 7.5 or 12.0 <= s < 30.0 for s in starts)
    assert any(s >= 12.0 for s in starts)


def test_all_active_ignores_the_activation_rates() -> None:
    p = build([4], [Job("a", exe=0.0625, cpu=1, cycle=0.125, activation=0.1)])
    r = simulate(p, np.array([0]), p.limits, duration_s=10.0, all_active=True)
    assert r.active_fraction[0] == 1.0
    assert r.cycles == 80


def test_compare_reports_medians_per_plan_and_module() -> None:
    p, placement = _noisy_problem()
    spread = np.array([0, 0, 0], dtype=np.int64)
    plans = {"packed": (placement, p.limits), "same": (spread, p.limits)}
    out = compare(p, plans, duration_s=20.0, seeds=[0, 1, 2])
    assert set(out) == {"packed", "same"}
    s = out["packed"]
    assert s["seeds"] == [0, 1, 2] and len(s["miss_rates"]) == 3
    rates = [m for m in s["miss_rates"] if m is not None]
    assert s["miss_rate"] == pytest.approx(float(np.median(rates)))
    assert set(s["module_miss_rate"]) == {"a", "b", "c"}
    assert out["packed"] == out["same"]  # same plan, same seeds: identical
