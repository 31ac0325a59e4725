"""A running fleet as the operator sees it: its objects read through a ``Source`` (the cluster
adapter, ``plugin.cluster``, or a fake), turned into the planning problem by the operator's own
steps (``controllers.inputs.gather``, ``observe.scaling_pools``, ``observed.profile_corrections``,
``domain.build.build_problem``, ``stickiness.mask_unavailable``), with the deployed placement
(``status.placement``, or the Deployments' node affinity above 1000 instances) and the
measured miss rates (``status.measured``, else the SoftwareModules' ``status.observed``).

A what-if (``WhatIf``) changes the objects before the build: a node removed (masked out as
unavailable), a robot added (a copy of another robot's ComputeNode and Node), a link slowed
(the robot planned with a measured latency, as ``domain.linkhealth`` would)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.labels import LABEL_FLEET
from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.controllers.inputs import current_placement, gather
from fogfleet.controllers.observe import parse_fleet, scaling_pools
from fogfleet.controllers.observed import profile_corrections
from fogfleet.domain.build import build_problem, refusals
from fogfleet.domain.network import Link, uplink
from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import label_value
from fogfleet.scheduling.stickiness import mask_unavailable

__all__ = ["Live", "Source", "WhatIf", "measured_rates", "read_fleet"]

Obj = dict[str, Any]
I64 = NDArray[np.int64]


class Source(Protocol):
    """What the plugin reads (``adapters.kube.KubeClient`` has these methods)."""

    def get_fleet(self, namespace: str, name: str) -> Obj | None: ...
    def list_modules(self, namespace: str | None) -> list[Obj]: ...
    def list_compute_nodes(self) -> list[Obj]: ...
    def list_nodes(self) -> list[Obj]: ...
    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...


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


@dataclass(frozen=True)
class Live:
    """A running fleet's problem, its deployed placement and what was measured."""

    raw: Obj  # the RobotFleet as read (with status)
    fleet: RobotFleet
    catalog: Catalog
    problem: Problem  # unavailable nodes masked out
    unavailable: dict[int, str]  # node index -> why
    placement: I64  # deployed (I,), -1 where unknown
    with_limits: bool
    raw_modules: list[Obj]
    current: dict[tuple[str, str, int], str]
    pools: dict[str, dict[str, int]]
    measured: dict[str, float]  # module -> measured miss rate

    def refused(self, i: int) -> dict[int, Any]:
        """Instance i's refusals by node (``domain.build.refusals``)."""
        return dict(
            refusals(
                self.fleet,
                self.catalog,
                self.problem.instances[i],
                self.current,
                self.pools,
                profile_corrections(self.raw_modules),
            )
        )

    @property
    def status(self) -> Obj:
        return dict(self.raw.get("status") or {})


def read_fleet(source: Source, namespace: str, name: str, what_if: WhatIf | None = None) -> Live:
    """The fleet ``namespace/name`` rebuilt as the operator builds it (see the docstring)."""
    raw = source.get_fleet(namespace, name)
    if raw is None:
        raise InvalidSpec(f"RobotFleet/{name}", "", f"not found in namespace {namespace}")
    w = what_if or WhatIf()
    raw_modules = source.list_modules(namespace)
    compute_nodes, nodes = source.list_compute_nodes(), source.list_nodes()
    if w.add_robot:
        raw, compute_nodes, nodes = _with_robot(raw, compute_nodes, nodes, w.add_robot, w.like)
    fleet = parse_fleet(raw)
    deployments = source.list_deployments(namespace, {LABEL_FLEET: label_value(name)})
    gathered = gather(fleet, compute_nodes, raw_modules, nodes)
    current = current_placement(deployments)
    pools = scaling_pools(raw_modules)
    measured = {n: _slowed(gathered.catalog, n, s) for n, s in w.links.items()}
    problem = build_problem(
        fleet, gathered.catalog, current, pools, measured, profile_corrections(raw_modules)
    )
    why = dict(gathered.unavailable) | {n: "removed (what-if)" for n in w.without_nodes}
    unavailable = {j: why[nd.name] for j, nd in enumerate(problem.nodes) if nd.name in why}
    masked, _ = mask_unavailable(problem, unavailable)
    return Live(
        raw=raw,
        fleet=fleet,
        catalog=gathered.catalog,
        problem=masked,
        unavailable=unavailable,
        placement=_deployed(problem, raw, deployments),
        with_limits=fleet.spec.scheduler.algorithm is not SchedulerName.ONBOARD,
        raw_modules=raw_modules,
        current=current,
        pools=pools,
        measured=measured_rates(raw, raw_modules),
    )


def _deployed(problem: Problem, raw: Obj, deployments: list[Obj]) -> I64:
    """Where each instance runs: ``status.placement`` (by Node name), else (a fleet above
    ``PLACEMENT_LIST_LIMIT`` instances lists none there) its Deployment's node affinity."""
    listed = (raw.get("status") or {}).get("placement") or []
    where: dict[tuple[str, str, int], str] = {
        (e.get("robot") or "", e["module"], int(e.get("replica") or 0)): e["node"] for e in listed
    }
    if not where:
        where = current_placement(deployments)
    index: dict[str, int] = {}
    for j, nd in enumerate(problem.nodes):
        index.setdefault(nd.node_name, j)
        index.setdefault(nd.name, j)
    out = np.full(problem.n_instances, -1, dtype=np.int64)
    for i, inst in enumerate(problem.instances):
        node = where.get((inst.robot, inst.module, inst.replica))
        if node is not None and node in index:
            out[i] = index[node]
    return out


def measured_rates(raw: Obj, raw_modules: list[Obj]) -> dict[str, float]:
    """Each module's measured miss rate: the fleet's ``status.measured`` (its pods, over the
    drift window), else the cycle-weighted ``missedPercent`` of the SoftwareModule's
    ``status.observed`` rows (every fleet's pods of the module)."""
    out: dict[str, float] = {}
    for m in (raw.get("status") or {}).get("measured") or []:
        if m.get("measuredMissRate") is not None:
            out[str(m["module"])] = float(m["measuredMissRate"])
    for mod in raw_modules:
        name = str(mod["metadata"]["name"])
        rows = [
            r
            for r in (mod.get("status") or {}).get("observed") or []
            if r.get("cycles") and r.get("missedPercent") is not None
        ]
        cycles = sum(float(r["cycles"]) for r in rows)
        if name not in out and cycles > 0:
            missed = sum(float(r["cycles"]) * float(r["missedPercent"]) for r in rows)
            out[name] = missed / cycles / 100.0
    return out


def _with_robot(
    raw: Obj, compute_nodes: list[Obj], nodes: list[Obj], name: str, like: str | None
) -> tuple[Obj, list[Obj], list[Obj]]:
    """The objects with robot ``name`` added as a copy of robot ``like``."""
    tmpl = next((c for c in compute_nodes if c["metadata"]["name"] == like), None)
    if tmpl is None:
        raise InvalidSpec(f"ComputeNode/{like}", "--like", "no such ComputeNode to copy")
    cn = copy.deepcopy(tmpl)
    cn["metadata"] = {"name": name, "labels": dict(tmpl["metadata"].get("labels") or {})}
    cn.pop("status", None)
    node_of = (tmpl.get("spec") or {}).get("nodeName") or like
    if (cn.get("spec") or {}).get("nodeName"):
        cn["spec"]["nodeName"] = name
    node = next((copy.deepcopy(n) for n in nodes if n["metadata"]["name"] == node_of), None)
    extra = []
    if node is not None:
        node["metadata"] = {"name": name, "labels": dict(node["metadata"].get("labels") or {})}
        extra.append(node)
    raw = copy.deepcopy(raw)
    robots = raw.setdefault("spec", {}).get("robots")
    if robots is not None and name not in robots:
        robots.append(name)
    return raw, [*compute_nodes, cn], [*nodes, *extra]


def _slowed(catalog: Catalog, robot: str, latency: float) -> Link:
    """Robot ``robot``'s declared uplink with ``latency`` (seconds)."""
    node = catalog.nodes.get(robot)
    if node is None:
        raise InvalidSpec(f"ComputeNode/{robot}", "--link", "no such ComputeNode")
    return replace(uplink(node.spec), latency=latency)
