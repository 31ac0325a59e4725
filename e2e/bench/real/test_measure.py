"""Window rates from counter snapshots (pure; no cluster)."""

from __future__ import annotations

import pytest

from e2e.bench.real.measure import Counts, snapshot, window_rates


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
