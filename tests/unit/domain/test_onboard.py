"""What a module that cannot leave its robot needs there (domain.onboard)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.observed import Observation
from fogfleet.domain.onboard import cpu_needed, onboard_needs, pinned_on_board
from fogfleet.domain.problem import Problem

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
PINNED = "nav-controller"  # hard real-time, safety-critical


@pytest.fixture(scope="module")
def problem() -> Problem:
    catalog = load_paths([WAREHOUSE])
    (fleet,) = catalog.fleets
    return build_problem(fleet, catalog)


def on_board(problem: Problem) -> np.ndarray:
    return np.where(problem.home >= 0, problem.home, 0).astype(np.int64)


def test_the_cpu_needed_scales_the_measured_time_to_the_cycle() -> None:
    # 40 ms under a 400m limit is 16 core-ms of work: within a 33 ms cycle it needs 485m
    assert cpu_needed(0.040, 0.4, 0.033) == pytest.approx(0.016 / 0.033)
    assert cpu_needed(0.020, 0.4, 0.040) == pytest.approx(0.2)  # half the cycle: half the CPU


def test_hard_real_time_instances_are_pinned_and_others_are_not(problem: Problem) -> None:
    pinned = {problem.instances[i].module for i in range(problem.n_instances)
              if pinned_on_board(problem, i)}  # fmt: skip
    assert PINNED in pinned
    assert any(not pinned_on_board(problem, i) for i in range(problem.n_instances))


def test_a_robot_short_for_its_pinned_module_says_by_how_much(problem: Problem) -> None:
    x = on_board(problem)
    i = next(i for i, inst in enumerate(problem.instances) if inst.module == PINNED)
    j = int(problem.home[i])
    hw, cycle = problem.nodes[j].hardware_type, float(problem.cycle[i])
    request = float(problem.limits.cpu_request[i, j])
    unreserved = np.full(problem.n_nodes, 0.5)
    unreserved[j] = 0.1
    # measured: the 95th percentile at four cycles under a 500m limit -> needs 2 cores
    slow = Observation(PINNED, hw, 0.5, 1000.0, 3 * cycle, 4 * cycle)
    fewer = Observation(PINNED, hw, 0.25, 10.0, cycle, cycle)  # fewer samples: not counted
    needs = onboard_needs(problem, x, PINNED, [fewer, slow], unreserved)
    worst = needs[0]
    assert worst.robot == problem.nodes[j].name
    assert worst.needed == pytest.approx(2.0)
    assert worst.available == pytest.approx(request + 0.1)
    assert worst.short == pytest.approx(2.0 - request - 0.1) and worst.short > 0
    # every robot of that hardware type runs one; those with more spare CPU are less short
    robots = {n.robot for n in needs}
    assert len(robots) == len(needs) > 1
    assert needs[-1].short == pytest.approx(2.0 - request - 0.5)


def test_a_robot_with_room_is_not_short(problem: Problem) -> None:
    x = on_board(problem)
    i = next(i for i, inst in enumerate(problem.instances) if inst.module == PINNED)
    hw, cycle = problem.nodes[int(problem.home[i])].hardware_type, float(problem.cycle[i])
    fits = Observation(PINNED, hw, 0.5, 1000.0, 0.3 * cycle, 0.5 * cycle)  # needs 250m
    needs = onboard_needs(problem, x, PINNED, [fits], np.zeros(problem.n_nodes))
    assert needs and all(n.short == 0.0 for n in needs)
    assert needs[0].needed == pytest.approx(0.25)


def test_a_module_that_can_move_has_no_onboard_need(problem: Problem) -> None:
    x = on_board(problem)
    free = next(
        inst.module for i, inst in enumerate(problem.instances)
        if inst.robot and not pinned_on_board(problem, i)
    )  # fmt: skip
    i = next(i for i, inst in enumerate(problem.instances) if inst.module == free)
    hw = problem.nodes[int(problem.home[i])].hardware_type
    obs = Observation(free, hw, 0.5, 1000.0, 1.0, 2.0)
    assert onboard_needs(problem, x, free, [obs], np.zeros(problem.n_nodes)) == []
    # no CPU limit measured: nothing to tell
    unlimited = Observation(PINNED, hw, None, 1000.0, 1.0, 2.0)
    assert onboard_needs(problem, x, PINNED, [unlimited], np.zeros(problem.n_nodes)) == []
