"""Learning a profile from measured execution times, and drift (domain.observed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.observed import (
    Observation,
    correction,
    declared_row,
    drift_due,
    drifting,
)
from fogfleet.domain.pairs import ProfileRow

ROWS = [ProfileRow(0.1, 0.040, 0.004), ProfileRow(0.2, 0.020, 0.002)]
WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"


def obs(cpu: float | None, n: float, mean: float, hw: str = "robot-nuc") -> Observation:
    return Observation("m", hw, cpu, n, mean, mean * 1.2)


def test_the_declared_row_is_the_one_the_workload_plays() -> None:
    assert declared_row(ROWS, 0.1) == ROWS[0]
    assert declared_row(ROWS, 0.15) == ROWS[0]  # the largest at or below the limit
    assert declared_row(ROWS, 0.05) == ROWS[0]  # below every row: the smallest
    assert declared_row(ROWS, None) == ROWS[1]  # no limit: the largest
    assert declared_row([], 0.1) is None


def test_std_comes_from_the_95th_percentile_as_a_normal_tail() -> None:
    assert Observation("m", "h", 0.1, 10, 0.100, 0.1329).std == pytest.approx(0.020, abs=1e-4)
    assert Observation("m", "h", 0.1, 10, 0.100, 0.090).std == 0.0


def test_the_correction_blends_measured_over_declared_with_the_prior_by_count() -> None:
    declared = {"robot-nuc": ROWS}
    # 300 cycles at 100m took 120 ms against 40 ms declared: 3x; prior 100 cycles of 1x
    got = correction([obs(0.1, 300, 0.120)], declared, prior=100)
    assert got["robot-nuc"] == pytest.approx(((100 + 300 * 3) / 400, 300))
    # two rows, each against its own declared mean, weighted by their counts
    got = correction([obs(0.1, 100, 0.080), obs(0.2, 300, 0.060)], declared, prior=0)
    assert got["robot-nuc"][0] == pytest.approx((100 * 2 + 300 * 3) / 400)
    # no prior and no measure: nothing; a type without declared rows: nothing
    assert correction([], declared, prior=100) == {}
    assert correction([obs(0.1, 50, 0.1, hw="other")], declared, prior=100) == {}


def test_a_large_prior_keeps_the_declared_profile_until_many_cycles_say_otherwise() -> None:
    few = correction([obs(0.1, 10, 0.120)], {"robot-nuc": ROWS}, prior=1000)
    many = correction([obs(0.1, 100000, 0.120)], {"robot-nuc": ROWS}, prior=1000)
    assert few["robot-nuc"][0] < 1.05 and many["robot-nuc"][0] > 2.9


def test_drift_is_a_miss_rate_above_the_prediction_by_the_margin() -> None:
    assert drifting(0.01, 0.07, 5) and not drifting(0.01, 0.05, 5)
    assert not drifting(0.01, None, 5)


def test_drift_re_plans_after_lasting_and_never_twice_within_the_interval() -> None:
    assert not drift_due(None, 100, 60, None, 300)
    assert not drift_due(50, 100, 60, None, 300)  # 50 s of drift: not yet
    assert drift_due(40, 100, 60, None, 300)
    assert not drift_due(40, 100, 60, 0, 300)  # re-planned for drift 100 s ago
    assert drift_due(40, 400, 60, 0, 300)


def test_the_planner_runs_the_declared_rows_times_the_correction() -> None:
    catalog = load_paths([WAREHOUSE])
    (fleet,) = catalog.fleets
    plain = build_problem(fleet, catalog)
    module = plain.instances[0].module
    hw = plain.nodes[int(plain.home[0])].hardware_type
    slow = build_problem(fleet, catalog, corrections={(module, hw): 3.0})
    rows = [i for i, inst in enumerate(plain.instances) if inst.module == module]
    i = rows[0]
    h = int(plain.home[i])
    assert plain.allowed[i, h] and slow.allowed[i, h]
    # the nominal row (the largest profiled CPU) runs exactly 3x longer
    assert slow.nominal.exe_mean[i, h] == pytest.approx(3 * plain.nominal.exe_mean[i, h])
    assert slow.nominal.exe_std[i, h] == pytest.approx(3 * plain.nominal.exe_std[i, h])
    # other modules and other hardware types are as declared
    same = np.flatnonzero([inst.module != module for inst in plain.instances])
    assert np.array_equal(plain.limits.exe_mean[same], slow.limits.exe_mean[same])
    edges = np.flatnonzero(plain.tier == 1)
    assert np.array_equal(plain.nominal.exe_mean[i, edges], slow.nominal.exe_mean[i, edges])
