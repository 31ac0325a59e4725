"""The room other tenants hold on a fleet's nodes, said in cores a user can act on: who holds
how many, what each node leaves the fleet, and what the fleet needs against it (issue 45)."""

from __future__ import annotations

from pathlib import Path

import pytest

from fogfleet.api.loader import load_paths
from fogfleet.domain.tenancy import Held
from fogfleet.snapshot import problem_of, room_note, snapshot_of_catalog

LITE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse-lite"


def test_nobody_else_on_the_fleets_nodes_says_nothing() -> None:
    catalog = load_paths([str(LITE)])
    held = {"elsewhere": Held().plus(4.0, 0.0, "RobotFleet a/x")}
    snapshot = snapshot_of_catalog(catalog, catalog.fleets[0], held)
    assert room_note(problem_of(snapshot), snapshot.held) == ""


def test_the_room_note_names_each_holder_and_the_cores_left_and_needed() -> None:
    catalog = load_paths([str(LITE)])
    edge = catalog.nodes["bed-edge-1"]
    held = {edge.node_name: Held().plus(0.5, 0.0, "RobotFleet a/x").plus(0.25, 0.0, "pods in ops")}
    snapshot = snapshot_of_catalog(catalog, catalog.fleets[0], held)
    alone = problem_of(snapshot_of_catalog(catalog, catalog.fleets[0]))
    problem = problem_of(snapshot)
    j = next(k for k, n in enumerate(problem.nodes) if n.name == "bed-edge-1")
    assert alone.capacity[j, 0] - problem.capacity[j, 0] == pytest.approx(0.75)  # planned around
    note = room_note(problem, snapshot.held)
    left, total = problem.capacity[j, 0], alone.capacity[j, 0]
    assert f"bed-edge-1 has {left:g} of {total:g} cores left" in note
    assert "(RobotFleet a/x 0.5, pods in ops 0.25 cores)" in note
    assert "other fleets and pods hold 0.75 cores on this fleet's nodes: it needs " in note
