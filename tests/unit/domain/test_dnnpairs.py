"""A split network in the planner (``domain.dnnpairs``, issue 48): its tail placed off board
with the split RoboEC2's rule picks over each node's link, its local model at home, and what
its robot holds whatever the plan (DNNSPLIT.md 3.2)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from tests.unit.splitfleet import DNN, HPE, ROBOT_SPEED, split_catalog

from fogfleet.api.loader import Catalog
from fogfleet.domain.build import build_problem, refusals
from fogfleet.domain.problem import Problem

SLOW = {"latencyMillis": 30, "jitterMillis": 3, "bandwidthMbps": 5}  # every offload too slow
MEDIUM = {"latencyMillis": 4, "jitterMillis": 3, "bandwidthMbps": 20}


def _problem(catalog: Catalog) -> Problem:
    (fleet,) = catalog.fleets
    return build_problem(fleet, catalog)


def _first(p: Problem) -> int:
    return next(i for i, inst in enumerate(p.instances) if inst.module == HPE)


def test_the_tail_is_planned_with_the_rules_action_and_the_robot_holds_head_and_local() -> None:
    p = _problem(split_catalog(DNN))
    i = _first(p)
    h = int(p.home[i])
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    # 120 Mbit/s wifi + LAN: full offload, 40.1 ms of raw frame + 4.3 ms each way + 3.8 ms
    # network + 0.3 ms answer, beats bneck's 50 ms head (time spotlight)
    full = 602112 * 8 / 120e6 + 4000 * 8 / 120e6 + 2 * 4.3e-3
    assert p.net_mean[i, edge] == pytest.approx(full, rel=1e-6)
    assert p.limits.exe_mean[i, edge] + p.net_mean[i, edge] <= 0.9 * 0.1
    assert p.limits.cpu_request[i, edge] == pytest.approx(0.1)  # 3.8 ms / 0.1 = 38 ms fits
    assert p.traffic[i] == pytest.approx((602112 + 4000) * 8 * 10)
    # the local model (accuracy 0.61 < 0.8) may not answer alone while an edge is left
    assert not p.allowed[i, h]
    # the robot holds the slower of the 50 ms head and the 10 ms local model: 50 ms fits
    # 90 ms at 0.75 core (67 ms), not at half a core (100 ms), whatever the plan
    assert p.standing_by[i] and p.fallback_row is not None
    assert p.fallback_row[i, 0] == pytest.approx(0.75)
    assert p.fallback_reserve(p.limits)[h, 0] >= 0.75


def test_a_link_too_slow_for_every_offboard_action_leaves_the_local_model_at_home() -> None:
    p = _problem(
        split_catalog(DNN, wifi={"latencyMillis": 30, "jitterMillis": 3, "bandwidthMbps": 5})
    )
    i = _first(p)
    h = int(p.home[i])
    assert not p.allowed[i, p.tier > 0].any()
    assert p.allowed[i, h]  # Algorithm 1: nothing left, the local model answers
    assert p.limits.exe_mean[i, h] == pytest.approx(
        0.4e-3 / ROBOT_SPEED / p.limits.cpu_request[i, h]
    )
    catalog = split_catalog(DNN, wifi=SLOW)
    (fleet,) = catalog.fleets
    why = refusals(fleet, catalog, p.instances[i])
    said = [str(w) for j, w in why.items() if w is not None and p.tier[j] == 1]
    assert said and all("over this link" in w and "maxLatency" in w for w in said)
    assert all(w.rule == "dnn" for j, w in why.items() if w is not None and p.tier[j] == 1)
    assert h not in why  # the local model may run at home


def test_a_slow_link_moves_the_choice_to_the_bottleneck_split() -> None:
    # 20 Mbit/s: the raw frame takes 241 ms, bneck's 6 KB 2.5 ms beside its 50 ms head
    p = _problem(
        split_catalog(DNN, wifi={"latencyMillis": 4, "jitterMillis": 3, "bandwidthMbps": 20})
    )
    i = _first(p)
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    outside = 2.0e-3 / ROBOT_SPEED + (6272 + 4000) * 8 / 20e6 + 2 * 4.3e-3
    assert p.net_mean[i, edge] == pytest.approx(outside, rel=1e-6)
    assert p.traffic[i] == pytest.approx((6272 + 4000) * 8 * 10)


@pytest.mark.parametrize(("spotlight", "offboard"), [("time", False), ("cost", True)])
def test_an_accurate_enough_local_model_runs_at_home_and_wins_on_time(
    spotlight: str, offboard: bool
) -> None:
    # the local model (10 ms on the robot) is faster than any off-board action (52 ms): the
    # time spotlight takes it over every link; the cost spotlight offloads (0 robot ms)
    dnn = {**copy.deepcopy(DNN), "minAccuracy": 0.5, "spotlight": spotlight}
    p = _problem(split_catalog(dnn))
    i = _first(p)
    assert p.allowed[i, int(p.home[i])]
    assert bool(p.allowed[i, p.tier == 1].any()) is offboard


def test_times_measured_on_the_robots_hardware_type_are_used_there_as_they_are() -> None:
    # the robots' own profile (no speed factor applied: it was measured there); the edges
    # keep the reference times divided by their speed
    robot_hw = "robot-nuc"
    measured = {
        "hardwareType": robot_hw,
        "inputBytes": 602112,
        "outputBytes": 4000,
        "fullMillis": 60.0,
        "localMillis": 8.0,
        "splitPoints": [
            {"name": "b6", "headMillis": 29.0, "tailMillis": 20.0, "tensorBytes": 401408},
            {"name": "bneck", "headMillis": 30.0, "tailMillis": 20.0, "tensorBytes": 6272},
        ],
    }
    p = _problem(split_catalog({**copy.deepcopy(DNN), "profiles": [measured]}, wifi=MEDIUM))
    i = _first(p)
    h = int(p.home[i])
    assert p.nodes[h].hardware_type == robot_hw
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    outside = 30e-3 + (6272 + 4000) * 8 / 20e6 + 2 * 4.3e-3
    assert p.net_mean[i, edge] == pytest.approx(outside, rel=1e-6)
    # the robot holds the slowest head it measured: 30 ms fits 90 ms at half a core
    assert p.fallback_row is not None and p.fallback_row[i, 0] == pytest.approx(0.5)


def test_a_network_without_times_on_a_hardware_type_waits_for_profiling_there() -> None:
    dnn = copy.deepcopy(DNN)
    for key in ("inputBytes", "outputBytes", "fullMillis"):
        dnn.pop(key)
    dnn["localModel"].pop("robotMillis")
    dnn["splitPoints"] = [{"name": s["name"]} for s in dnn["splitPoints"]]
    catalog = split_catalog(dnn, profiling={"mode": "auto"})
    p = _problem(catalog)
    i = _first(p)
    assert not p.allowed[i].any()
    (fleet,) = catalog.fleets
    why = [w for w in refusals(fleet, catalog, p.instances[i]).values() if w is not None]
    assert why and all(w.rule == "profile" for w in why)
    assert any("no times of its network for hardware type 'robot-nuc'" in str(w) for w in why)
