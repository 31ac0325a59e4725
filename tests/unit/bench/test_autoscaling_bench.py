"""The tinyKube benchmark: determinism, sane metrics, the table."""

import numpy as np
import pytest

from fogfleet.bench.autoscaling import (
    METRICS,
    POLICIES,
    format_table,
    make_workload,
    run_benchmark,
    simulate,
)


def small(seed: int):  # type: ignore[no-untyped-def]
    return make_workload(seed, phases=2, requests_per_phase=400)


def test_workload_is_a_function_of_the_seed() -> None:
    a, b, c = small(3), small(3), small(4)
    assert np.array_equal(a.arrival, b.arrival) and np.array_equal(a.private, b.private)
    assert not np.array_equal(a.arrival, c.arrival)
    assert all(5 <= robots <= 50 and 20 <= rate <= 100 for robots, rate in a.phases)
    assert np.all(np.diff(a.arrival) > 0)


@pytest.mark.parametrize("policy", sorted(POLICIES))
def test_simulation_is_deterministic_per_seed(policy: str) -> None:
    workload = small(7)
    first = simulate(workload, POLICIES[policy], 7)
    again = simulate(workload, POLICIES[policy], 7)
    assert first == again
    assert set(first) == set(METRICS)
    for key in ("privacyRejected", "normalRejected", "sloViolations"):
        assert 0.0 <= first[key] <= 1.0
    # at least the 10 initial replicas for the whole run
    assert first["replicaSeconds"] >= 10 * (workload.arrival[-1] - 5.0)


def test_format_table_reports_medians_side_by_side() -> None:
    runs = {
        1: {"a": dict.fromkeys(METRICS, 0.1), "b": dict.fromkeys(METRICS, 0.3)},
        2: {"a": dict.fromkeys(METRICS, 0.2), "b": dict.fromkeys(METRICS, 0.5)},
        3: {"a": dict.fromkeys(METRICS, 0.9), "b": dict.fromkeys(METRICS, 0.4)},
    }
    table = format_table(runs).splitlines()
    assert table[0].split()[-2:] == ["a", "b"]
    row = next(line for line in table if line.startswith("privacyRejected"))
    assert row.split()[1:] == ["20.00%", "40.00%"]
    assert "median of 3 seeds" in table[0]


@pytest.mark.integration
def test_full_benchmark_is_deterministic() -> None:
    assert run_benchmark(11) == run_benchmark(11)
