"""How many instances a change to a fleet's nodes makes move at the least: the "had to move"
of a fault's report (issue 46: "instances moved at most twice the number that had to move").

Those that ran on a node the fleet no longer has, plus the fewest running instances any
placement moves to make room for them: the pure core's own exact solver
(``scheduling.room.fewest_moves``) over every node, on the fleet's objects as applied and the
placement its status reported before the change.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.domain.build import build_problem
from fogfleet.scheduling.heuristics import Fit
from fogfleet.scheduling.room import fewest_moves
from fogfleet.scheduling.stickiness import still_fitting, usable_current

__all__ = ["fewest_to_move"]


def fewest_to_move(
    docs: Iterable[Mapping[str, Any]], nodes: list[str], placement: Iterable[Mapping[str, Any]]
) -> int:
    """The fewest instances that move when the fleet of ``docs`` (one RobotFleet, its
    modules and ComputeNodes) keeps only ``nodes``, from ``placement`` (status.placement
    entries: robot, module, replica, node)."""
    catalog = Catalog()
    for doc in docs:
        catalog.add(parse_object(doc))
    (fleet,) = catalog.fleets
    changed = fleet.model_copy(update={"spec": fleet.spec.model_copy(update={"nodes": nodes})})
    return _fewest(changed, catalog, placement)


def _fewest(fleet: RobotFleet, catalog: Catalog, placement: Iterable[Mapping[str, Any]]) -> int:
    node_name = {n.metadata.name: n.node_name for n in catalog.nodes.values()}
    current = {
        (p.get("robot") or "", p["module"], int(p.get("replica") or 0)): node_name[p["node"]]
        for p in placement
        if p.get("node") in node_name
    }
    problem = build_problem(fleet, catalog, current)
    fit = Fit(problem, problem.limits)
    kept = still_fitting(problem, fit, usable_current(problem))
    todo = problem.allowed.any(axis=1) & (kept < 0)
    if not todo.any():
        return 0
    x = np.where(todo, -1, kept)
    made = fewest_moves(problem, x, todo, fit, kept >= 0, nodes_tried=problem.n_nodes)
    assert made is not None, "the fleet fits nowhere after the change"
    return int(todo.sum()) + int(np.sum((kept >= 0) & (made != kept)))
