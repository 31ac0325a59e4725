"""Where a fleet's instances run, as its status says: one entry per instance up to
PLACEMENT_LIST_LIMIT instances (``PlacementEntry``), a compact form above it
(``CompactPlacement``: a few bytes per instance), and the count per tier (``ModulePlacement``).

Both per-instance forms hold the same facts (robot, module, replica, node, tier, CPU);
``placement_entries_of`` reads either as entries, so a reader never asks which one a fleet has."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from pydantic import Field, ValidationError, model_validator

from .base import FogModel, parse_cpu
from .dnn import DnnChoice

__all__ = [
    "PLACEMENT_LIST_LIMIT",
    "CompactModulePlacement",
    "CompactPlacement",
    "ModulePlacement",
    "PlacementEntry",
    "placement_entries_of",
]

Obj = dict[str, Any]

# A RobotFleet must stay well below etcd's 1.5 MiB object limit, and its status is rewritten at
# every step of a rollout: one placement entry is about 110 bytes of JSON, so a 1000-robot
# fleet's 8000 made the object 0.9 MiB and each status patch took 0.6 s of the API server on an
# idle bed. Beyond this many instances status.placement is left empty and
# status.placementCompact says the same in about 16 bytes per instance.
PLACEMENT_LIST_LIMIT = 1000


class PlacementEntry(FogModel):
    """Where one module instance runs."""

    robot: str
    """The robot the instance serves (empty for a shared module's replica)."""
    module: str
    """The SoftwareModule."""
    node: str
    """The Kubernetes Node its pod is bound to (node affinity)."""
    tier: str
    """robot, edge or cloud."""
    cpu: str | None = None
    """CPU request = limit given to the instance, in cores."""
    replica: int | None = None
    """Replica index of a shared module."""
    split: DnnChoice | None = None
    """A split network's (SoftwareModule spec.dnn): the action taken with its tail on this
    node, and why."""


class ModulePlacement(FogModel):
    """How many instances of one module run on each tier."""

    module: str
    """The SoftwareModule."""
    robot: int = 0
    """Instances on the robots' own computers."""
    edge: int = 0
    """Instances on edge nodes."""
    cloud: int = 0
    """Instances in the cloud."""


class CompactModulePlacement(FogModel):
    """Where one module's instances run: position k of each list is one instance."""

    module: str
    """The SoftwareModule."""
    robot: list[int] = Field(default_factory=list)
    """The robot each instance serves, as its index in placementCompact.robots (-1: a shared
    module's replica)."""
    replica: list[int] = Field(default_factory=list)
    """Each instance's replica index, for a shared module (empty for a per-robot module: every
    instance is replica 0)."""
    node: list[int] = Field(default_factory=list)
    """The Node each instance runs on, as its index in placementCompact.nodes."""
    milli_cpu: list[int] = Field(default_factory=list)
    """The CPU request = limit given to each instance, in millicores."""

    @model_validator(mode="after")
    def _check(self) -> CompactModulePlacement:
        lengths = {len(self.robot), len(self.node), len(self.milli_cpu)}
        if self.replica:
            lengths.add(len(self.replica))
        if len(lengths) != 1:
            raise ValueError(
                f"module {self.module}: robot, replica, node and milliCpu must list one value "
                f"per instance each, got {len(self.robot)}, {len(self.replica)}, "
                f"{len(self.node)} and {len(self.milli_cpu)}"
            )
        return self


class CompactPlacement(FogModel):
    """status.placement's facts for a fleet of more than 1000 instances, each name written
    once: the robots and the nodes as tables, then per module one index per instance."""

    robots: list[str] = Field(default_factory=list)
    """The robots that the modules' robot lists index."""
    nodes: list[str] = Field(default_factory=list)
    """The Nodes that the modules' node lists index."""
    tiers: list[str] = Field(default_factory=list)
    """Each Node's tier (robot, edge or cloud), in the order of nodes."""
    modules: list[CompactModulePlacement] = Field(default_factory=list)
    """Per module, where its instances run."""

    @model_validator(mode="after")
    def _check(self) -> CompactPlacement:
        if len(self.tiers) != len(self.nodes):
            raise ValueError(f"{len(self.nodes)} nodes but {len(self.tiers)} tiers")
        for m in self.modules:
            if any(not 0 <= j < len(self.nodes) for j in m.node):
                raise ValueError(f"module {m.module}: a node index outside nodes")
            if any(not -1 <= r < len(self.robots) for r in m.robot):
                raise ValueError(f"module {m.module}: a robot index outside robots")
        return self

    @classmethod
    def of(cls, entries: Sequence[Mapping[str, Any]]) -> CompactPlacement:
        """The compact form of placement entries (``PlacementEntry``'s wire form, CPU in
        millicores as the operator writes it); a split network's choice is left out (its
        SoftwareModule's status.split says it)."""
        robots: dict[str, int] = {}
        nodes: dict[str, int] = {}
        tiers: list[str] = []
        modules: dict[str, dict[str, list[int]]] = {}
        for e in entries:
            node = str(e["node"])
            if node not in nodes:
                nodes[node] = len(nodes)
                tiers.append(str(e["tier"]))
            robot = str(e.get("robot") or "")
            if robot and robot not in robots:
                robots[robot] = len(robots)
            lists = modules.setdefault(
                str(e["module"]), {"robot": [], "replica": [], "node": [], "milli_cpu": []}
            )
            lists["robot"].append(robots[robot] if robot else -1)
            lists["replica"].append(int(e.get("replica") or 0))
            lists["node"].append(nodes[node])
            lists["milli_cpu"].append(_millicores(e.get("cpu")))
        for lists in modules.values():
            if not any(lists["replica"]):
                lists["replica"] = []  # a per-robot module's: every instance is replica 0
        return cls(
            robots=list(robots),
            nodes=list(nodes),
            tiers=tiers,
            modules=[CompactModulePlacement(module=m, **lists) for m, lists in modules.items()],
        )

    def entries(self) -> list[Obj]:
        """The placement entries it holds, in ``PlacementEntry``'s wire form."""
        out: list[Obj] = []
        for m in self.modules:
            replicas = m.replica or [0] * len(m.node)
            for r, replica, j, milli in zip(m.robot, replicas, m.node, m.milli_cpu, strict=True):
                entry: Obj = {
                    "robot": self.robots[r] if r >= 0 else "",
                    "module": m.module,
                    "node": self.nodes[j],
                    "tier": self.tiers[j],
                    "cpu": f"{milli}m",
                }
                if r < 0:
                    entry["replica"] = replica
                out.append(entry)
        return out


def _millicores(cpu: Any) -> int:
    """The operator's CPU quantity ("250m") in millicores; 0 when the entry has none."""
    if cpu in (None, ""):
        return 0
    return round(parse_cpu(cpu) * 1000)


def placement_entries_of(status: Mapping[str, Any]) -> list[Obj]:
    """A fleet status's placement entries (``PlacementEntry``'s wire form): status.placement,
    else status.placementCompact read back; [] when it has neither, or a compact form this
    operator did not write."""
    listed = status.get("placement") or []
    if listed:
        return [dict(e) for e in listed]
    compact = status.get("placementCompact")
    if not compact:
        return []
    try:
        return CompactPlacement.model_validate(compact).entries()
    except ValidationError:
        return []
