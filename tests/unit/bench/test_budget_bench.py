"""The planning-budget benchmark (``fogfleet bench budget``): its rows for the fleet that fits
and for the same robots on a tenth of the edges, short of CPU."""

import pytest

from fogfleet.bench.budget import budget_rows


@pytest.mark.integration  # four small plans: over a second
def test_the_budget_bench_plans_the_fleet_that_fits_and_the_one_short_of_cpu() -> None:
    rows = budget_rows(robots=20, budgets=[1000], runs=1, short_budgets=[1000])
    fits, short = rows
    assert (fits["edges"], short["edges"]) == (8, 2)
    assert fits["feasible"] and fits["degraded"] == 0 and fits["gap_pct"] is not None
    # the short fleet is planned degraded, and a degraded plan has no gap
    assert short["feasible"] and short["degraded"] > 0 and short["gap_pct"] is None
    assert all(
        r["seconds"] > 0 and r["over_budget_max"] == pytest.approx(r["seconds_max"] / 1, abs=0.01)
        for r in rows
    )
    assert budget_rows(robots=20, budgets=[1000], runs=1, short_budgets=[])[0].keys() == fits.keys()
