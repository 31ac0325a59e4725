"""Hand-computed cycles, misses, CPU sharing and utilisation of tiny plans."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from simkit import Job, build

from fogfleet.sim import simulate

# Binary fractions (1/8 s, 1/16 s) keep the hand-computed times exact in floating point;
# aligned_start=True starts every always-active instance's first cycle at t = 0.


def test_job_alone_with_slack_never_misses() -> None:
    p = build([16], [Job("a", exe=0.0625, cpu=1, cycle=0.125)])
    r = simulate(p, np.array([0]), p.limits, aligned_start=True, duration_s=10.0)
    assert r.cycles == 80  # starts at 0, 0.125, ..., 9.875
    assert r.missed == 0
    assert r.miss_rate == 0.0
    assert r.module_p95_cycle_s["a"] == pytest.approx(0.0625)


def test_job_slower_than_its_cycle_always_misses() -> None:
    p = build([16], [Job("a", exe=0.25, cpu=1, cycle=0.125)])
    r = simulate(p, np.array([0]), p.limits, aligned_start=True, duration_s=10.0)
    assert r.cycles == 40  # back to back: the next cycle starts when the last one ends
    assert r.missed == 40
    assert r.module_miss_rate["a"] == 1.0


def test_two_jobs_wanting_two_cores_on_a_two_core_node_run_at_half_speed() -> None:
    jobs = [Job("a", exe=0.0625, cpu=2, cycle=0.25), Job("b", exe=0.0625, cpu=2, cycle=0.25)]
    p = build([2], jobs)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=10.0)
    # both start together, each gets 1 core: 0.0625 s of work take 0.125 s; no miss
    assert r.module_p95_cycle_s["a"] == pytest.approx(0.125)
    assert r.missed == 0
    assert list(r.instance_cycles) == [40, 40]
    # with a cycle of 0.1 s every cycle misses and they run back to back
    tight = [Job("a", exe=0.0625, cpu=2, cycle=0.1), Job("b", exe=0.0625, cpu=2, cycle=0.1)]
    p = build([2], tight)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=10.0)
    assert list(r.instance_cycles) == [80, 80]
    assert r.miss_rate == 1.0
    assert r.node_utilisation[0] == pytest.approx(1.0)


def test_staggered_jobs_share_only_while_they_overlap() -> None:
    # a starts executing at 0; b's input transfer takes 0.05 s, so b joins at 0.05.
    # 0-0.05: a alone (0.05 done); 0.05-0.15: both at half speed (a finishes);
    # 0.15-0.2: b alone (finishes), then 0.05 s output transfer: b's cycle takes 0.25 s.
    jobs = [
        Job("a", exe=0.1, cpu=2, cycle=0.24),
        Job("b", exe=0.1, cpu=2, cycle=0.24, net=0.1),
    ]
    p = build([2], jobs)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=0.2)
    assert r.module_p95_cycle_s["a"] == pytest.approx(0.15)
    assert r.module_p95_cycle_s["b"] == pytest.approx(0.25)
    assert list(r.instance_missed) == [0, 1]
    assert r.node_utilisation[0] == pytest.approx(1.0)  # 2 cores busy from 0 to 0.2


def test_a_limited_job_is_not_sped_up_by_idle_cores() -> None:
    p = build([8], [Job("a", exe=0.3, cpu=1, cycle=1.0)])
    r = simulate(p, np.array([0]), p.limits, aligned_start=True, duration_s=5.0)
    assert r.module_p95_cycle_s["a"] == pytest.approx(0.3)
    assert r.node_utilisation[0] == pytest.approx(5 * 0.3 * 1 / (8 * 5.0))


def test_a_busy_node_shares_its_cpu_by_the_jobs_requests() -> None:
    # demands 1 + 4 on 4 cores, requests (CFS weights) 1 and 4: shares 0.8 and 3.2, both slow
    jobs = [Job("small", exe=0.25, cpu=1, cycle=1.0), Job("big", exe=0.375, cpu=4, cycle=1.0)]
    p = build([4], jobs)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=1.0)
    assert r.module_p95_cycle_s["small"] == pytest.approx(0.25 / 0.8)  # 0.3125
    # big: 0.3125 s at 0.8 speed (0.25 done), then the remaining 0.125 alone
    assert r.module_p95_cycle_s["big"] == pytest.approx(0.4375)


def test_node_utilisation_is_busy_core_seconds_over_capacity() -> None:
    jobs = [Job("a", exe=0.0625, cpu=2, cycle=0.125), Job("b", exe=0.5, cpu=1, cycle=1.0)]
    p = build([4, 2, 6], jobs)
    r = simulate(p, np.array([0, 1]), p.limits, aligned_start=True, duration_s=10.0)
    assert r.node_utilisation[0] == pytest.approx(80 * 0.0625 * 2 / (4 * 10.0))  # 0.25
    assert r.node_utilisation[1] == pytest.approx(10 * 0.5 * 1 / (2 * 10.0))  # 0.25
    assert r.node_utilisation[2] == 0.0


def test_utilisation_counts_only_the_horizon() -> None:
    # one cycle starting at 0 that runs 3 s on 1 core, horizon 2 s on a 1-core node
    p = build([1], [Job("a", exe=3.0, cpu=1, cycle=10.0)])
    r = simulate(p, np.array([0]), p.limits, aligned_start=True, duration_s=2.0)
    assert r.cycles == 1  # it started inside the horizon, so it is run to completion
    assert r.node_utilisation[0] == pytest.approx(1.0)


def test_unplaced_instances_are_skipped_and_reported() -> None:
    jobs = [Job("a", exe=0.0625, cpu=1, cycle=0.125), Job("b", exe=0.0625, cpu=1, cycle=0.125)]
    p = build([4], jobs)
    r = simulate(p, np.array([0, -1]), p.limits, aligned_start=True, duration_s=1.0)
    assert r.unplaced == (1,)
    assert list(r.instance_cycles) == [8, 0]
    assert math.isnan(r.instance_miss_rate[1])
    assert math.isnan(r.module_miss_rate["b"])
    d = r.to_dict()
    assert d["unplaced"] == ["r1/b"]
    json.dumps(d, allow_nan=False)  # NaN became null


def test_a_plan_outside_the_gene_space_is_rejected() -> None:
    p = build([4, 4], [Job("a", exe=0.1, cpu=1, cycle=1.0)])
    exe = p.limits.exe_mean.copy()
    exe[0, 1] = np.inf
    alloc = type(p.limits)(p.limits.cpu_request, p.limits.cpu_use, exe, p.limits.exe_std, True)
    with pytest.raises(ValueError, match="cannot run"):
        simulate(p, np.array([1]), alloc)
    with pytest.raises(ValueError, match="shape"):
        simulate(p, np.array([0, 0]), p.limits)
    with pytest.raises(ValueError, match="placement values"):
        simulate(p, np.array([2]), p.limits)


def test_instances_active_from_the_start_begin_at_a_random_phase() -> None:
    jobs = [Job("a", exe=0.0625, cpu=2, cycle=0.25), Job("b", exe=0.0625, cpu=2, cycle=0.25)]
    p = build([2], jobs)
    r = simulate(p, np.array([0, 0]), p.limits, duration_s=10.0, seed=1)
    # out of lockstep the two jobs overlap only partly: faster than the aligned 0.125 s
    assert 0.0625 <= r.module_p95_cycle_s["a"] < 0.125
    assert list(r.instance_cycles) in ([40, 40], [39, 40], [40, 39], [39, 39])


def test_the_fleet_figure_is_the_mean_over_modules_so_a_slow_module_cannot_hide() -> None:
    # "fast" runs 16 cycles for each of "slow"'s 1 and never misses; "slow" always misses
    jobs = [Job("fast", exe=0.0078125, cpu=1, cycle=0.0625), Job("slow", exe=2.0, cpu=1, cycle=1.0)]
    p = build([16], jobs)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=10.0)
    assert r.module_miss_rate == {"fast": 0.0, "slow": 1.0}
    assert r.missed / r.cycles < 0.05  # weighting every cycle alike would hide "slow"
    assert r.miss_rate == pytest.approx(0.5)
