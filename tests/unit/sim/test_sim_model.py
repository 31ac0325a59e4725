"""The execution model beyond the declared profile (issue 49): how a short node's CPU is
spread, and the cycle's cost the closed loop measures."""

from __future__ import annotations

import numpy as np
import pytest
from simkit import Job, build

from fogfleet.domain.rows import Learnt
from fogfleet.sim import DECLARED, ExecutionModel, simulate
from fogfleet.sim.engine import newest_first

# a starts executing at 0; b's input transfer takes 0.05 s, so b joins at 0.05 (both want the
# node's 2 cores, each has 0.1 s of work in a 0.24 s cycle)
STAGGERED = [Job("a", exe=0.1, cpu=2, cycle=0.24), Job("b", exe=0.1, cpu=2, cycle=0.24, net=0.1)]


def _staggered(spread: float) -> tuple[list[float], list[int]]:
    p = build([2], STAGGERED)
    r = simulate(p, np.array([0, 0]), p.limits, aligned_start=True, duration_s=0.2, spread=spread)
    return [r.module_p95_cycle_s["a"], r.module_p95_cycle_s["b"]], list(r.instance_missed)


def test_processor_sharing_stretches_both_cycles_and_the_later_one_misses() -> None:
    # 0-0.05 a alone; 0.05-0.15 both at half speed (a ends); 0.15-0.2 b alone; + 0.05 out
    durations, missed = _staggered(0.0)
    assert durations == pytest.approx([0.15, 0.25])
    assert missed == [0, 1]


def test_the_job_that_woke_last_keeps_its_pace_and_the_running_one_absorbs_the_shortage() -> None:
    # 0-0.05 a alone (half its work); 0.05-0.15 b has both cores (ends, + 0.05 out: 0.2);
    # 0.15-0.2 a finishes its other half: both cycles take 0.2 s, neither misses
    durations, missed = _staggered(1.0)
    assert durations == pytest.approx([0.2, 0.2])
    assert missed == [0, 0]


def test_a_spread_between_mixes_the_two_shares() -> None:
    # spread 0.5: from 0.05 b gets 0.5 x 1 + 0.5 x 2 = 1.5 cores and a 0.5; b's 0.1 s of work
    # at 2 cores is 0.2 core-s: done at 0.05 + 0.2 / 1.5, then 0.05 out
    durations, _ = _staggered(0.5)
    assert durations[1] == pytest.approx(0.05 + 0.2 / 1.5 + 0.05)


def test_newest_first_fills_the_latest_job_up_to_its_demand() -> None:
    assert newest_first([1.0, 1.0, 1.0], 1.5, [0.0, 0.2, 0.1]) == [0.0, 1.0, 0.5]
    assert newest_first([0.4, 0.4], 1.5, [0.0, 0.1]) == [0.4, 0.4]  # both fit
    assert newest_first([1.0, 1.0], 1.0, [0.1, 0.1]) == [0.0, 1.0]  # tie: the later in list


def test_a_spread_outside_zero_to_one_is_refused() -> None:
    p = build([2], STAGGERED)
    with pytest.raises(ValueError, match="spread must lie in"):
        simulate(p, np.array([0, 0]), p.limits, spread=1.5)
    with pytest.raises(ValueError, match="spread must lie in"):
        ExecutionModel(spread=-0.1)


def test_an_idle_node_is_the_same_under_every_spread() -> None:
    p = build([4], STAGGERED)  # 4 cores: the two jobs never share
    a = simulate(p, np.array([0, 0]), p.limits, duration_s=5.0, seed=3)
    b = simulate(p, np.array([0, 0]), p.limits, duration_s=5.0, seed=3, spread=1.0)
    assert list(a.instance_missed) == list(b.instance_missed)
    assert a.module_p95_cycle_s == b.module_p95_cycle_s


def test_the_cycles_cost_slows_the_module_on_its_hardware_type_only() -> None:
    # 0.1 s of work in a 0.12 s cycle: a factor of 1.3 makes every cycle 0.13 s, a miss
    p = build([4], [Job("a", exe=0.1, cpu=1, cycle=0.12), Job("b", exe=0.1, cpu=1, cycle=0.12)])
    placement = np.array([0, 0])
    slow = ExecutionModel({("a", "default"): Learnt(1.3, 0.0, 500)})
    r = slow.simulate(p, placement, p.limits, 5.0, 1, all_active=True)
    assert r.module_miss_rate["a"] == 1.0
    assert r.module_miss_rate["b"] == 0.0
    other_type = ExecutionModel({("a", "pi4"): Learnt(1.3, 0.0, 500)})
    assert other_type.simulate(p, placement, p.limits, 5.0, 1).module_miss_rate["a"] == 0.0
    assert DECLARED.simulate(p, placement, p.limits, 5.0, 1).module_miss_rate["a"] == 0.0


def test_the_cycles_noise_makes_some_cycles_miss() -> None:
    p = build([4], [Job("a", exe=0.1, cpu=1, cycle=0.12)])
    noisy = ExecutionModel({("a", "default"): Learnt(1.0, 0.02, 500)})  # 20 ms: z = 1
    rate = noisy.simulate(p, np.array([0]), p.limits, 60.0, 1).module_miss_rate["a"]
    assert 0.08 < rate < 0.25  # lognormal with mean 0.1, std 0.02: P(> 0.12) is about 0.15


def test_a_model_reads_back_what_it_wrote_and_names_a_missing_field() -> None:
    model = ExecutionModel({("nav-controller", "pi4"): Learnt(1.07, 0.0081, 1186)}, 0.3, "pilot x")
    back = ExecutionModel.from_json(model.as_json())
    assert back.spread == 0.3
    assert back.source == "pilot x"
    got = back.corrections[("nav-controller", "pi4")]
    assert (got.factor, got.noise, got.noise_cycles) == pytest.approx((1.07, 0.0081, 1186))
    with pytest.raises(ValueError, match="spread"):
        ExecutionModel.from_json({"corrections": []})
    with pytest.raises(ValueError, match="factor must be > 0"):
        ExecutionModel({("m", "pi4"): Learnt(0.0, 0.0)})
