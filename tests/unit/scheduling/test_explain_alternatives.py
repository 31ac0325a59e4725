"""scheduling.explain.alternatives on the warehouse example: each reason is the planner's own
answer."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.build import build_problem, refusals
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.explain.alternatives import explain_module
from fogfleet.scheduling.heuristics import greedy_schedule
from fogfleet.scheduling.objectives import objective_values

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"


@cache
def _warehouse() -> tuple[Any, Any, Any, np.ndarray]:
    cat = load_paths([str(WAREHOUSE)])
    fleet = cat.fleets[0]
    problem = build_problem(fleet, cat)
    return cat, fleet, problem, greedy_schedule(problem, SchedulerSettings(seed=1)).placement


def _why(module: str, robot: str | None = None) -> Any:
    cat, fleet, problem, x = _warehouse()
    return explain_module(
        problem,
        x,
        True,
        module,
        robot=robot,
        refused=lambda i: refusals(fleet, cat, problem.instances[i]),
    )


def test_hard_realtime_module_is_refused_every_edge_by_the_taxonomy() -> None:
    why = _why("nav-controller", "robot-2")
    (inst,) = why.instances
    assert inst.node == "robot-2"
    edges = [a for a in inst.alternatives if a.tier == "edge"]
    assert len(edges) == 6
    assert {a.rule for a in edges} == {"taxonomy"}
    assert "hard real-time or safety-critical" in edges[0].reason


def test_device_refusal_names_the_missing_device() -> None:
    (inst,) = _why("nav-localization", "robot-1").instances
    assert {a.rule for a in inst.alternatives} == {"device"}
    assert "lidar" in inst.alternatives[0].reason


def test_capacity_reason_says_the_amounts_from_the_evaluation() -> None:
    problem = _warehouse()[2]
    why = _why("scene-segmentation")
    full = [a for i in why.instances for a in i.alternatives if a.rule == "capacity"]
    assert full, "some node is too full for scene-segmentation"
    a = full[0]
    assert a.reason.startswith("needs 4 cpu but ") and " free" in a.reason
    j = problem.node_index(a.node)
    assert a.node in a.reason and str(int(problem.capacity[j, 0])) in a.reason.replace("m", "")


def test_worse_reason_is_the_moved_plans_evaluation_difference() -> None:
    _, _, problem, x = _warehouse()
    why = _why("scene-segmentation")
    found = [
        (inst, a)
        for inst in why.instances
        for a in inst.alternatives
        if a.rule == "objectives" and a.reason.startswith("allowed, but worse on")
    ]
    assert found
    inst, a = found[0]
    i = next(k for k, s in enumerate(problem.instances) if problem.label(k) == inst.label)
    moved = x.copy()
    moved[i] = problem.node_index(a.node)
    names = list(a.deltas)
    before = objective_values(problem, x, True, names)
    after = objective_values(problem, moved, True, names)
    for n in names:
        assert a.deltas[n] == pytest.approx(after[n] - before[n], abs=1e-9)
    worst = a.reason.removeprefix("allowed, but worse on ").split(" by ")[0]
    assert a.deltas[worst] > 0


def test_unknown_module_or_robot_is_bad_input() -> None:
    with pytest.raises(InvalidSpec, match="has no instance of module"):
        _why("no-such-module")
    with pytest.raises(InvalidSpec, match="has no instance of module"):
        _why("nav-controller", "robot-99")


def test_unavailable_node_is_said_so() -> None:
    _, _, problem, x = _warehouse()
    from fogfleet.scheduling.stickiness import mask_unavailable

    j = problem.node_index("edge-1")
    masked, _ = mask_unavailable(problem, {j: "NotReady"})
    why = explain_module(
        masked,
        np.where(x == j, -1, x),
        True,
        "nav-motion-planning",
        robot="robot-1",
        unavailable={j: "NotReady"},
    )
    (edge1,) = [a for a in why.instances[0].alternatives if a.node == "edge-1"]
    assert edge1.rule == "unavailable" and "NotReady" in edge1.reason


def test_a_full_node_names_who_else_holds_it() -> None:
    """With ``held`` (the room other fleets and pods hold), a capacity reason says who."""
    from fogfleet.domain.tenancy import Held

    _, _, problem, x = _warehouse()
    plain = [a for i in _why("scene-segmentation").instances for a in i.alternatives]
    node = next(a.node for a in plain if a.rule == "capacity")
    k8s_node = problem.nodes[problem.node_index(node)].node_name
    held = {k8s_node: Held().plus(2.0, 0.0, "RobotFleet north/other")}
    why = explain_module(problem, x, True, "scene-segmentation", held=held)
    reasons = [a.reason for i in why.instances for a in i.alternatives if a.node == node]
    assert reasons and all(
        r.endswith("; other fleets and pods hold 2 more there (RobotFleet north/other 2 cores)")
        for r in reasons
        if "cpu but" in r
    ), reasons
    assert not any("other fleets" in a.reason for a in plain)
