"""The benchmark's fleet: ``e2e/bench/real/paper`` (the paper's IV-C experiment on the ``paper``
bed profile), on the cluster and offline.

On the cluster every run gets its own namespace (a run never sees the previous run's pods or
counters); offline the same objects give the Problem the simulator runs the measured
placements on.

**Honest requests** (issue 49, the ``k8s-requests`` arm). ``k8s-default`` requests each
module's declared CPU (``spec.resources.cpu``: 33m for a perception pod that uses 150-240m),
so kube-scheduler packs blindly. A careful Kubernetes user sets the request from a profiling
run on the reference hardware instead: ``honest_requests`` takes, for every module, the
smallest of its rows on the reference hardware (the i9 rows, ``hardwareType: default`` in
``paper/modules.yaml``, which both edges run) whose mean plus three standard deviations fits
its cycle time (human-pose-estimation: 267m, 60 + 3 x 6 = 78 ms in a 100 ms cycle; 133m's
100 + 3 x 10 ms does not fit), and the largest row where none fits. The requests are computed
from the profile by this code, not written down, and fixed before the arm's first run: they
depend on nothing the bed measures. ``Scenario(requests=...)`` applies them to the
SoftwareModules, so the Deployments and the simulator's nominal allocation request them.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.commandline.cli.planning import recorded_placement
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Allocation, Problem

__all__ = [
    "EXAMPLE",
    "FLEET",
    "PROFILE",
    "REFERENCE",
    "SCALE",
    "SIGMAS",
    "Request",
    "Scenario",
    "honest_requests",
]

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = Path(__file__).resolve().parent / "paper"
FLEET = "paper"
PROFILE = "paper"  # the bed profile whose real nodes the ComputeNodes describe
SCALE = 15  # the factor nodes.yaml and modules.yaml divide the paper's CPU figures by

REFERENCE = "default"  # the i9 rows of paper/modules.yaml: the reference hardware
SIGMAS = 3.0  # a request's row: mean + SIGMAS x std within the cycle time

Obj = dict[str, Any]


@dataclass(frozen=True)
class Request:
    """A module's honest CPU request and the profile row it was read from."""

    module: str
    cpu: str  # as the row writes it ("267m")
    mean_ms: float
    std_ms: float
    cycle_ms: float
    fits: bool  # False: no reference row fits the cycle; the largest is requested

    def as_json(self) -> dict[str, Any]:
        return {
            "cpu": self.cpu,
            "meanMillis": self.mean_ms,
            "stdMillis": self.std_ms,
            "cycleMillis": self.cycle_ms,
            "fits": self.fits,
        }

    def describe(self) -> str:
        """ "human-pose-estimation 267m (60 + 3 x 6 ms <= 100 ms)"."""
        sign = "<=" if self.fits else ">"
        return (
            f"{self.module} {self.cpu} ({self.mean_ms:g} + {SIGMAS:g} x {self.std_ms:g} ms "
            f"{sign} {self.cycle_ms:g} ms)"
        )


def honest_requests(
    modules: Iterable[Mapping[str, Any]],
    hardware_type: str = REFERENCE,
    sigmas: float = SIGMAS,
) -> dict[str, Request]:
    """Module -> its request (module docstring): the smallest CPU among the module's rows of
    ``hardware_type`` whose mean + ``sigmas`` x std fits its cycle time, else its largest
    row; modules without a row of that type are left out (they keep their declared CPU)."""
    out: dict[str, Request] = {}
    for m in modules:
        spec, name = m["spec"], str(m["metadata"]["name"])
        cycle = float(spec["cycleTimeMillis"])
        rows = sorted(
            (r for r in spec.get("profile") or [] if r.get("hardwareType") == hardware_type),
            key=lambda r: parse_cpu(r["cpu"]),
        )
        if not rows:
            continue
        fit = [r for r in rows if r["meanMillis"] + sigmas * r["stdMillis"] <= cycle]
        row = fit[0] if fit else rows[-1]
        out[name] = Request(
            name, str(row["cpu"]), float(row["meanMillis"]), float(row["stdMillis"]), cycle,
            bool(fit),
        )  # fmt: skip
    return out


class Scenario:
    def __init__(self, folder: Path = EXAMPLE, requests: Mapping[str, str] | None = None) -> None:
        """The fleet of ``folder``; ``requests`` (module -> CPU) replaces those modules'
        ``spec.resources.cpu`` (the ``k8s-requests`` arm)."""
        self.folder = folder
        self.requests = dict(requests or {})
        self.docs: list[Obj] = [
            d
            for path in sorted(folder.glob("*.yaml"))
            for d in yaml.safe_load_all(path.read_text())
            if isinstance(d, dict) and d.get("kind") != "Namespace"
        ]
        for d in self.docs:
            if d["kind"] == "SoftwareModule" and d["metadata"]["name"] in self.requests:
                d["spec"]["resources"]["cpu"] = self.requests[d["metadata"]["name"]]
        catalog = Catalog()
        for d in self.docs:
            catalog.add(parse_object(d), str(folder))
        fleet = next(f for f in catalog.fleets if f.metadata.name == FLEET)
        self.problem: Problem = build_problem(fleet, catalog)

    def with_honest_requests(self) -> Scenario:
        """This fleet with every module requesting its ``honest_requests`` CPU."""
        got = honest_requests(self.of_kind("SoftwareModule"))
        return Scenario(self.folder, {m: r.cpu for m, r in got.items()})

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

    def due_cycles(self, instances: Iterable[tuple[str, str]], window_s: float) -> dict[str, float]:
        """Per module, the cycles ``instances`` ((module, robot) each) were due over a window
        of ``window_s``: the window over each one's cycle time."""
        cycle = {(inst.module, inst.robot): float(self.problem.cycle[i])
                 for i, inst in enumerate(self.problem.instances)}  # fmt: skip
        due: dict[str, float] = {}
        for key in instances:
            due[key[0]] = due.get(key[0], 0.0) + window_s / cycle[key]
        return due

    def placement_of(self, fleet_object: Obj) -> tuple[Any, Allocation]:
        """The placement the cluster ran (the fleet's status) and the allocation it ran with."""
        return recorded_placement(self.problem, fleet_object, "RobotFleet status")
