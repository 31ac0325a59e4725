"""Migrations as an objective (issue 10): a re-plan that counts its moves moves fewer."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import warehouse_problem
from fogfleet.scheduling.solver import plan

WITH_MOVES = ["missRate", "migrations", "missedCycles", "onboard", "reserve", "balance"]


@pytest.mark.integration
def test_a_replan_that_counts_its_moves_keeps_more_in_place_at_the_same_miss_rate() -> None:
    problem = warehouse_problem()
    settings = SchedulerSettings(population=40, generations=30, seed=3)
    running = dataclasses.replace(problem, current=np.asarray(plan(problem, settings).placement))
    again = settings.model_copy(update={"seed": 4})
    plain = plan(running, again)
    counted = plan(running, again.model_copy(update={"objectives": WITH_MOVES}))

    def moved(x: object) -> int:
        return int(((running.current >= 0) & (np.asarray(x) != running.current)).sum())

    assert moved(counted.placement) < moved(plain.placement)
    assert counted.objectives["migrations"] == moved(counted.placement)
    assert counted.objectives["missRate"] <= plain.objectives["missRate"] + 1e-3
