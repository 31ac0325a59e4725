"""``snapshot.build``: the one way every entry point turns a snapshot into its planning problem,
step by step (built, released robots freed, unavailable nodes masked), as the operator uses it
(issue 45 item 1)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fogfleet.api.loader import load_paths
from fogfleet.snapshot import FleetSnapshot, build, problem_of, snapshot_of_catalog

LITE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse-lite"


def _running_on_the_edge() -> FleetSnapshot:
    """The warehouse-lite fleet with every instance running on the edge (where it may)."""
    catalog = load_paths([str(LITE)])
    snapshot = snapshot_of_catalog(catalog, catalog.fleets[0])
    problem = problem_of(snapshot)
    current = {(i.robot, i.module, i.replica): "bed-edge-1" for i in problem.instances}
    return dataclasses.replace(snapshot, current=current)


def test_a_released_robots_instances_are_planned_as_not_running_yet() -> None:
    snapshot = _running_on_the_edge()
    kept = build(snapshot)
    released = build(dataclasses.replace(snapshot, released=frozenset({"bed-robot-1"})))
    problem = released.problem
    edge = problem.node_index("bed-edge-1")
    of_robot_1 = np.array([i.robot == "bed-robot-1" for i in problem.instances])
    on_edge = kept.before == edge  # every instance the edge may run (the rest are pinned)
    assert (on_edge & of_robot_1).any() and (on_edge & ~of_robot_1).any()
    assert (released.before[of_robot_1] == -1).all()  # free to go where the plan puts them
    assert (released.before[~of_robot_1] == kept.before[~of_robot_1]).all()  # the others stay
    assert (released.problem.current == released.before).all()  # nothing down: nothing masked
    same = problem_of(dataclasses.replace(snapshot, released=frozenset({"bed-robot-1"})))
    assert (same.current == released.problem.current).all()  # problem_of is build's last step


def test_a_node_down_is_masked_and_its_robots_only_instances_stranded() -> None:
    snapshot = dataclasses.replace(_running_on_the_edge(), unavailable={"bed-robot-2": "NotReady"})
    got = build(snapshot)
    robot_2 = got.built.node_index("bed-robot-2")
    assert got.built.allowed[:, robot_2].any() and not got.problem.allowed[:, robot_2].any()
    assert len(got.built.nodes) == len(got.problem.nodes)  # masked, not removed
    for i in got.stranded:  # stranded: could run before, no node left now
        assert got.built.allowed[i].any() and not got.problem.allowed[i].any()
    assert (got.before == got.built.current).all()  # before masking: where they ran
