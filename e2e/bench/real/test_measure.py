"""Window rates from counter snapshots (pure; no cluster)."""

from __future__ import annotations

import math

import pytest

from e2e.bench.real.measure import (
    Counts,
    counting_unrun,
    simulated_rates,
    snapshot,
    window_rates,
)


def test_a_windows_rate_is_the_difference_of_two_snapshots_per_module() -> None:
    before = Counts(
        cycles={("pose", "r1"): 100, ("pose", "r2"): 50, ("plan", "r1"): 10},
        missed={("pose", "r1"): 10, ("pose", "r2"): 0},
    )
    after = Counts(
        cycles={("pose", "r1"): 200, ("pose", "r2"): 150, ("plan", "r1"): 30},
        missed={("pose", "r1"): 30, ("pose", "r2"): 20, ("plan", "r1"): 0},
    )
    rates = window_rates(before, after)
    # pose: (20 + 20) missed of (100 + 100) cycles; plan: 0 of 20 -> the mean over modules
    assert rates.modules == {"pose": pytest.approx(0.2), "plan": 0.0}
    assert rates.cycles == {"pose": 200, "plan": 20}
    assert rates.missed == {"pose": 40, "plan": 0}
    assert rates.pooled(["pose", "plan", "absent"]) == (40, 220)
    assert rates.miss_rate == pytest.approx(0.1)


def test_an_instance_that_was_not_there_before_the_window_counts_nothing() -> None:
    before = Counts(cycles={("pose", "r1"): 10}, missed={})
    after = Counts(cycles={("pose", "r1"): 20, ("seg", "r1"): 500}, missed={("seg", "r1"): 400})
    assert set(window_rates(before, after).modules) == {"pose"}


def test_snapshot_sums_per_module_and_robot_in_the_namespace() -> None:
    asked: list[str] = []

    def query(promql: str) -> list[dict[str, object]]:
        asked.append(promql)
        return [{"metric": {"module": "pose", "robot": "r1"}, "value": [0, "7"]}]

    counts = snapshot(query, "ns-1")
    assert counts.cycles == {("pose", "r1"): 7.0}
    assert all('namespace="ns-1"' in q and "sum by (module, robot)" in q for q in asked)


def test_an_instance_left_pending_misses_every_cycle_it_was_due() -> None:
    before = Counts(cycles={("pose", "r1"): 100}, missed={("pose", "r1"): 0})
    after = Counts(cycles={("pose", "r1"): 700}, missed={("pose", "r1"): 6})
    # a second pose instance (10 Hz) Pending through a 60 s window, and a whole module
    rates = counting_unrun(window_rates(before, after), {"pose": 600.0, "seg": 300.0})
    assert rates.cycles == {"pose": 1200, "seg": 300}
    assert rates.missed == {"pose": 606, "seg": 300}
    assert rates.modules == {"pose": pytest.approx(606 / 1200), "seg": 1.0}
    assert counting_unrun(window_rates(before, after), {}) == window_rates(before, after)


def test_the_simulators_rates_count_alike() -> None:
    sim = simulated_rates({"pose": 0.01, "seg": math.nan}, {"pose": 600, "seg": 0})
    assert sim.missed == {"pose": 6, "seg": 0}
    rates = counting_unrun(sim, {"seg": 300.0})
    assert rates.modules == {"pose": pytest.approx(0.01), "seg": 1.0}
    assert rates.pooled(["pose", "seg"]) == (306, 900)
