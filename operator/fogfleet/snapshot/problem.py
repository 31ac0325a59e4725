"""``problem_of``: a snapshot (perhaps changed by a what-if) into the planning problem, the one
way every entry point builds it (the operator, every ``fogfleet`` command, every ``kubectl
fogfleet`` command): built from the snapshot, the robots whose link recovered released
(their instances planned as if they did not run yet), the unavailable nodes masked out of the
gene spaces. ``build`` returns the steps the operator needs as well (the problem as built, the
placement before masking, the stranded instances).

A what-if (``WhatIf``) changes the snapshot before the build: a node removed (masked out as
unavailable), a robot added (a copy of another robot's ComputeNode and Node: it needs the
listed objects), a link slowed (the robot planned with a measured latency, as
``domain.linkhealth`` would)."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.build import build_problem, refusals
from fogfleet.domain.network import Link, uplink
from fogfleet.domain.pairs import Refusal
from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.stickiness import mask_unavailable, release_robots

from .snapshot import FleetSnapshot, Listed, snapshot_of

__all__ = [
    "Built",
    "WhatIf",
    "build",
    "built_problem",
    "problem_of",
    "refused",
    "unavailable_in",
    "with_what_if",
]

Obj = dict[str, Any]


@dataclass(frozen=True)
class WhatIf:
    """Changes to plan for without applying them."""

    without_nodes: tuple[str, ...] = ()  # ComputeNodes removed
    add_robot: str | None = None  # a new robot's name ...
    like: str | None = None  # ... copied from this robot's ComputeNode and Node
    links: Mapping[str, float] = field(default_factory=dict)  # robot -> latency, seconds

    @property
    def empty(self) -> bool:
        return not (self.without_nodes or self.add_robot or self.links)


def with_what_if(snapshot: FleetSnapshot, what_if: WhatIf | None) -> FleetSnapshot:
    """``snapshot`` as it would be with ``what_if``'s changes."""
    if what_if is None or what_if.empty:
        return snapshot
    if what_if.add_robot:
        if snapshot.listed is None:
            raise InvalidSpec(f"RobotFleet/{snapshot.key[1]}", "--add-robot", "needs a cluster")
        listed = _with_robot(snapshot.listed, what_if.add_robot, what_if.like)
        snapshot = snapshot_of(listed, snapshot.held, snapshot.measured_links)
    links = {n: _slowed(snapshot, n, s) for n, s in what_if.links.items()}
    removed = {n: "removed (what-if)" for n in what_if.without_nodes}
    return dataclasses.replace(
        snapshot,
        measured_links={**snapshot.measured_links, **links},
        unavailable={**snapshot.unavailable, **removed},
    )


def built_problem(snapshot: FleetSnapshot) -> Problem:
    """The fleet's problem as built from the snapshot, before unavailable nodes are masked."""
    return build_problem(
        snapshot.fleet,
        snapshot.catalog,
        snapshot.current,
        snapshot.pools,
        snapshot.measured_links,
        snapshot.corrections,
    )


@dataclass(frozen=True)
class Built:
    """A snapshot's problem, step by step: ``built`` as built (every node the fleet
    references), ``before`` where its instances run (the released robots' as not running
    yet), ``problem`` as planned (unavailable nodes masked out) and the instances ``stranded``
    with no node left."""

    built: Problem
    before: NDArray[np.int64]  # node index per instance, -1: not running
    problem: Problem
    stranded: frozenset[int]


def build(snapshot: FleetSnapshot, what_if: WhatIf | None = None) -> Built:
    """``snapshot`` (changed by ``what_if``) into its planning problem: built, its released
    robots' instances freed (``stickiness.release_robots``), its unavailable nodes masked out
    (``stickiness.mask_unavailable``: an instance whose robot is down keeps its node, and one
    in a managed cluster that is unavailable stays there, stranded)."""
    snapshot = with_what_if(snapshot, what_if)
    built = built_problem(snapshot)
    released = [j for j, n in enumerate(built.nodes) if n.name in snapshot.released]
    problem = release_robots(built, released) if released else built
    # a managed cluster cut off runs on what it runs (OCM's pull model): pinned, not re-planned
    clusters = {
        j
        for j, nd in enumerate(problem.nodes)
        if nd.name in snapshot.catalog.nodes
        and snapshot.catalog.nodes[nd.name].spec.managed_cluster
    }
    masked, stranded = mask_unavailable(problem, unavailable_in(snapshot, problem), clusters)
    return Built(built, problem.current, masked, frozenset(stranded))


def problem_of(snapshot: FleetSnapshot, what_if: WhatIf | None = None) -> Problem:
    """The planning problem of ``snapshot`` (changed by ``what_if``): ``build``'s last step."""
    return build(snapshot, what_if).problem


def unavailable_in(snapshot: FleetSnapshot, problem: Problem) -> dict[int, str]:
    """Node index of ``problem`` -> why the snapshot says it cannot run pods."""
    why = snapshot.unavailable
    return {j: why[nd.name] for j, nd in enumerate(problem.nodes) if nd.name in why}


def refused(snapshot: FleetSnapshot, problem: Problem, i: int) -> dict[int, Refusal | None]:
    """Why instance ``i`` of ``problem`` may not run on each node (``domain.build.refusals``,
    asked with what the problem was built from)."""
    return refusals(
        snapshot.fleet,
        snapshot.catalog,
        problem.instances[i],
        snapshot.current,
        snapshot.pools,
        snapshot.corrections,
    )


def _with_robot(listed: Listed, name: str, like: str | None) -> Listed:
    """The objects with robot ``name`` added as a copy of robot ``like``."""
    tmpl = next((c for c in listed.compute_nodes if c["metadata"]["name"] == like), None)
    if tmpl is None:
        raise InvalidSpec(f"ComputeNode/{like}", "--like", "no such ComputeNode to copy")
    cn = copy.deepcopy(tmpl)
    cn["metadata"] = {"name": name, "labels": dict(tmpl["metadata"].get("labels") or {})}
    cn.pop("status", None)
    node_of = (tmpl.get("spec") or {}).get("nodeName") or like
    if (cn.get("spec") or {}).get("nodeName"):
        cn["spec"]["nodeName"] = name
    node = next((copy.deepcopy(n) for n in listed.nodes if n["metadata"]["name"] == node_of), None)
    extra = []
    if node is not None:
        node["metadata"] = {"name": name, "labels": dict(node["metadata"].get("labels") or {})}
        extra.append(node)
    raw = copy.deepcopy(listed.fleet)
    robots = raw.setdefault("spec", {}).get("robots")
    if robots is not None and name not in robots:
        robots.append(name)
    return dataclasses.replace(
        listed,
        fleet=raw,
        compute_nodes=[*listed.compute_nodes, cn],
        nodes=[*listed.nodes, *extra],
    )


def _slowed(snapshot: FleetSnapshot, robot: str, latency: float) -> Link:
    """Robot ``robot``'s declared uplink with ``latency`` (seconds)."""
    node = snapshot.catalog.nodes.get(robot)
    if node is None:
        raise InvalidSpec(f"ComputeNode/{robot}", "--link", "no such ComputeNode")
    return dataclasses.replace(uplink(node.spec), latency=latency)
