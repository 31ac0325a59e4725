"""The benchmark's fleet: ``e2e/bench/real/paper`` (the paper's IV-C experiment on the ``paper``
bed profile), on the cluster and offline.

On the cluster every run gets its own namespace (a run never sees the previous run's pods or
counters); offline the same objects give the Problem the simulator runs the measured
placements on.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

from fogfleet.api.loader import load_paths
from fogfleet.cli.planning import recorded_placement
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Allocation, Problem

__all__ = ["EXAMPLE", "FLEET", "PROFILE", "SCALE", "Scenario"]

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = Path(__file__).resolve().parent / "paper"
FLEET = "paper"
PROFILE = "paper"  # the bed profile whose real nodes the ComputeNodes describe
SCALE = 15  # the factor nodes.yaml and modules.yaml divide the paper's CPU figures by

Obj = dict[str, Any]


class Scenario:
    def __init__(self, folder: Path = EXAMPLE) -> None:
        self.folder = folder
        self.docs: list[Obj] = [
            d
            for path in sorted(folder.glob("*.yaml"))
            for d in yaml.safe_load_all(path.read_text())
            if isinstance(d, dict) and d.get("kind") != "Namespace"
        ]
        catalog = load_paths([str(folder)])
        fleet = next(f for f in catalog.fleets if f.metadata.name == FLEET)
        self.problem: Problem = build_problem(fleet, catalog)

    def of_kind(self, kind: str) -> list[Obj]:
        return [copy.deepcopy(d) for d in self.docs if d["kind"] == kind]

    def nodes(self) -> list[Obj]:
        """The ComputeNodes (cluster-scoped; their names are the bed's real Nodes)."""
        return self.of_kind("ComputeNode")

    def namespaced(
        self, namespace: str, scheduler: str, drift: Obj | None = None, seed: int | None = None
    ) -> list[Obj]:
        """The SoftwareModules and the RobotFleet in ``namespace``, planned by ``scheduler``
        (with ``drift`` as its ``spec.drift`` and ``seed`` as the planner's seed, if given)."""
        out = self.of_kind("SoftwareModule") + self.of_kind("RobotFleet")
        for d in out:
            d["metadata"]["namespace"] = namespace
            if d["kind"] == "RobotFleet":
                d["spec"]["scheduler"]["algorithm"] = scheduler
                if seed is not None:
                    d["spec"]["scheduler"]["seed"] = seed
                if drift is not None:
                    d["spec"]["drift"] = dict(drift)
        return out

    def hardware(self) -> list[dict[str, str]]:
        """The bed's nodes as bench-real.json names them: name, CPU, hardware type."""
        return [
            {
                "name": n["metadata"]["name"],
                "cpu": str(n["spec"]["capacity"]["cpu"]),
                "hardwareType": n["spec"]["hardwareType"],
            }
            for n in self.nodes()
        ]

    @property
    def instances(self) -> int:
        return self.problem.n_instances

    def placement_of(self, fleet_object: Obj) -> tuple[Any, Allocation]:
        """The placement the cluster ran (the fleet's status) and the allocation it ran with."""
        return recorded_placement(self.problem, fleet_object, "RobotFleet status")
