"""A split network's pods (``render.dnn``, issue 48): the tail on the node the plan chose, the
head on the robot with what the robot holds for it, both told the network and the action the
planner took; a plan that keeps the module at home runs the head alone with the local model."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from tests.unit.splitfleet import DNN, HPE, ROBOT_SPEED, split_catalog

from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import render_fleet

SLOW = {"latencyMillis": 30, "jitterMillis": 3, "bandwidthMbps": 5}


def _render(wifi: dict[str, float] | None = None) -> tuple[Problem, list[dict[str, Any]]]:
    """Each instance on the first node it may use, preferring an edge (a plan, not a search)."""
    catalog = split_catalog(DNN, wifi=wifi)
    (fleet,) = catalog.fleets
    p = build_problem(fleet, catalog)
    edge_first = np.where(p.tier[None, :] == 1, 0, 1) + np.arange(p.n_nodes)[None, :] * 1e-3
    placement = np.where(p.allowed, edge_first, np.inf).argmin(axis=1)
    modules = {m.metadata.name: m for m in catalog.modules.values()}
    return p, render_fleet(p, modules, placement)


def _pods(deps: list[dict[str, Any]]) -> list[tuple[str, dict[str, str], dict[str, Any]]]:
    """Per Deployment of the split module on robot-1: its node, env and resources."""
    out = []
    for d in deps:
        env = {
            e["name"]: e.get("value", "")
            for e in d["spec"]["template"]["spec"]["containers"][0]["env"]
        }
        if env["FOGFLEET_MODULE"] == HPE and env["FOGFLEET_ROBOT"] == "robot-1":
            out.append(
                (
                    env["FOGFLEET_NODE"],
                    env,
                    d["spec"]["template"]["spec"]["containers"][0]["resources"],
                )
            )
    return out


def test_the_tail_runs_where_planned_and_the_head_on_its_robot_with_the_planned_action() -> None:
    p, deps = _render()
    (tail_node, tail, _), (head_node, head, head_res) = _pods(deps)
    assert tail["FOGFLEET_ROLE"] == "tail" and head["FOGFLEET_ROLE"] == "head"
    assert tail_node.startswith("edge") and head_node == "robot-1"
    for env in (tail, head):
        dnn = json.loads(env["FOGFLEET_MODULE_SPEC"])["dnn"]
        # 120 Mbit/s: the whole network off board beats bneck's 50 ms head (domain tests)
        assert dnn["plannedAction"] == "full offload"
        assert dnn["maxLatencyMillis"] == pytest.approx(100)
        assert dnn["robotFactor"] == pytest.approx(1 / ROBOT_SPEED)
        assert dnn["tailFactor"] == pytest.approx(1.0)
        assert dnn["splitPoints"][1]["name"] == "bneck"
    i = next(k for k, inst in enumerate(p.instances) if inst.module == HPE)
    assert p.fallback_row is not None
    assert head_res["requests"]["cpu"] == f"{round(p.fallback_row[i, 0] * 1000)}m"  # 750m


def test_a_plan_that_keeps_the_network_at_home_runs_the_head_alone_with_the_local_model() -> None:
    _, deps = _render(SLOW)
    ((node, env, _),) = _pods(deps)
    assert node == "robot-1" and env["FOGFLEET_ROLE"] == "head"
    dnn = json.loads(env["FOGFLEET_MODULE_SPEC"])["dnn"]
    assert dnn["plannedAction"] == "tiny" and "tailFactor" not in dnn


def test_the_fleet_status_names_each_split_instances_action_and_why() -> None:
    from types import SimpleNamespace

    from fogfleet.api.v1alpha1.robotfleet import PlacementEntry
    from fogfleet.controllers.fleet.status import placement_entries

    p, deps = _render()
    placement = np.where(p.allowed, np.where(p.tier[None, :] == 1, 0, 1), 9).argmin(axis=1)
    decision = SimpleNamespace(placement=placement)
    entries = placement_entries(p, deps, SimpleNamespace(bound={}), decision, False)  # type: ignore[arg-type]
    split = [e for e in entries if e["module"] == HPE]
    assert len(split) == 5  # one per robot: the head Deployments stand behind their tails
    for e in split:
        assert e["split"]["action"] == "full offload"
        assert PlacementEntry.model_validate(e).split is not None
    assert all("split" not in e for e in entries if e["module"] != HPE)
