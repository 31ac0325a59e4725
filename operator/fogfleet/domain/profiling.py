"""Automatic profiling, the pure part (issue 10): what to profile, at which CPU limits, and
the profile fitted from what the Jobs measured.

**Where.** A module with ``profiling.mode: auto`` needs a profile on every hardware type of
the fleet's nodes it may run on (its tiers, its robot only when it must stay on board, a
shared module never on a robot: the rules of ``domain.pairs``) and has no rows for, neither
declared nor ``default`` nor profiled before.

**Which limits.** FogROS2-Config benchmarks a few edge-case machines instead of the whole
grid and fits from them. Here the grid is the module's ``profiling.cpus`` that a node of the
type can give at all; the Jobs measure its smallest and largest limit and the one closest to
their geometric middle (three Jobs whatever the grid's size; every limit of a grid of three
or fewer).

**The fit.** With ``c`` cores a cycle of ``W`` CPU-seconds of single-threaded work takes
about ``W / c`` (processor sharing, the simulator's job model, ``sim.engine``) plus fixed
costs: a line in ``1 / c``. A real CPU limit is a CFS quota per 100 ms period, which makes it
a staircase instead (on the bed, 10 ms of work took 185 ms at 50m, whose 5 ms a period
cannot hold it, and 24 ms at 100m, which can), so one curve through the measured limits can
be far off between them (a least-squares ``a + b / c`` was 228 % off at the bed's middle
limit). The rows between two measured limits are therefore interpolated linearly in ``1 / c``
between those two (exact for ``a + b / c``, never beyond its neighbours for a staircase),
their spread likewise; measured rows are written as measured. How far to trust the fitted
rows is reported: the middle measured limit as the two ends predict it, against what it
measured.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fogfleet.api.v1alpha1.base import format_millicores, parse_cpu, status_part
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.dnn import DnnHardwareProfile
from fogfleet.api.v1alpha1.profiling import ProfiledRow, ProfilingStatus
from fogfleet.api.v1alpha1.softwaremodule import (
    ProfileEntry,
    Scope,
    SoftwareModule,
    auto_profiled,
)

from .taxonomy import must_stay_onboard

__all__ = [
    "Fit",
    "Measurement",
    "current_rows",
    "dnn_limit",
    "edge_cases",
    "fit_profile",
    "grid_for",
    "module_spec_hash",
    "needed_profiles",
    "profiling_status",
    "with_profiled",
    "with_profiled_dnn",
    "with_profiled_rows",
]


@dataclass(frozen=True)
class Measurement:
    """What one profiling Job measured at one CPU limit."""

    cpu: float  # cores
    mean_ms: float
    std_ms: float
    cycles: int
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0


@dataclass(frozen=True)
class Fit:
    """The rows of a grid, measured or interpolated, and how far interpolation is off."""

    error_percent: float | None  # the middle measured limit predicted from the ends (None: < 3)
    rows: tuple[ProfiledRow, ...]


def module_spec_hash(module: SoftwareModule) -> str:
    """What a profile of the module depends on: its container, cycle and profiling settings
    (not its declared rows). A change to any of them profiles the module again."""
    spec = module.spec
    basis: dict[str, object] = {
        "template": spec.template.wire(),
        "cycle": str(spec.cycle_time_millis),
        "profiling": spec.profiling.wire() if spec.profiling is not None else None,
    }
    if spec.dnn is not None:  # what a Job times: the image's parts of these names
        basis["dnn"] = [p.name for p in spec.dnn.split_points]
    text = json.dumps(basis, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:10]


def edge_cases(grid: Sequence[float]) -> list[float]:
    """The limits to measure: all of a grid of three or fewer, else its smallest, its largest
    and the one closest to their geometric middle (ties: the smaller)."""
    cpus = sorted(set(grid))
    if len(cpus) <= 3:
        return cpus
    lo, hi = cpus[0], cpus[-1]
    middle = math.sqrt(lo * hi)
    inner = cpus[1:-1]
    mid = min(inner, key=lambda c: (round(abs(math.log(c / middle)), 9), c))
    return [lo, mid, hi]


def dnn_limit(capacities: Iterable[float]) -> float:
    """The CPU limit a split network's Job gets on a hardware type: one core (the network
    runs on one thread), or the largest node's usable CPU below that (0: none)."""
    return min(1.0, max(capacities, default=0.0))


def grid_for(module: SoftwareModule, capacities: Iterable[float]) -> list[float]:
    """The module's profiling grid (cores, ascending) that the largest node of a hardware type
    can give (``capacities``: those nodes' CPU less what they keep reserved)."""
    assert module.spec.profiling is not None
    most = max(capacities, default=0.0)
    return sorted({parse_cpu(c) for c in module.spec.profiling.cpus if parse_cpu(c) <= most + 1e-9})


def _may_run_on(module: SoftwareModule, node: ComputeNode) -> bool:
    """The tier rules of ``domain.pairs`` that do not depend on the profile."""
    spec, tier = module.spec, node.spec.tier
    if tier is Tier.ROBOT and spec.scope is Scope.SHARED:
        return False  # shared replicas never run on a robot
    if must_stay_onboard(spec.taxonomy) and tier is not Tier.ROBOT:
        return False
    req = spec.requirements
    return not (req.tiers and tier not in req.tiers)


def needed_profiles(
    modules: Iterable[SoftwareModule], nodes: Iterable[ComputeNode]
) -> dict[str, dict[str, list[ComputeNode]]]:
    """module name -> hardware type -> the fleet's nodes of that type, for every module with
    automatic profiling that may run there and has no rows for the type (``modules`` carry
    their profiled rows already: ``with_profiled_rows``)."""
    nodes = list(nodes)
    out: dict[str, dict[str, list[ComputeNode]]] = {}
    for mod in modules:
        if not auto_profiled(mod.spec):
            continue
        have = {r.hardware_type for r in mod.spec.profile}
        if mod.spec.dnn is not None:  # a split network: its times per type
            have = {p.hardware_type for p in mod.spec.dnn.profiles}
        if "default" in have:
            continue  # every type has rows: the default ones, speed-scaled
        for node in nodes:
            hw = node.spec.hardware_type
            if hw not in have and _may_run_on(mod, node):
                out.setdefault(mod.metadata.name, {}).setdefault(hw, []).append(node)
    return out


def fit_profile(hardware_type: str, grid: Sequence[float], measured: Sequence[Measurement]) -> Fit:
    """The rows of ``grid`` on ``hardware_type`` from the Jobs' ``measured`` limits (see the
    module docstring)."""
    if not measured:
        raise ValueError("nothing measured to fit")
    points = sorted(measured, key=lambda m: m.cpu)
    by_cpu = {round(m.cpu, 6): m for m in points}
    rows: list[ProfiledRow] = []
    for cpu in sorted(set(grid) | set(by_cpu)):
        m = by_cpu.get(round(cpu, 6))
        if m is not None:
            rows.append(
                ProfiledRow(
                    hardware_type=hardware_type,
                    cpu=format_millicores(cpu),
                    mean_millis=round(m.mean_ms, 3),
                    std_millis=round(m.std_ms, 3),
                    source="measured",
                    cycles=m.cycles,
                )
            )
            continue
        mean, std = _between(points, cpu)
        rows.append(
            ProfiledRow(
                hardware_type=hardware_type,
                cpu=format_millicores(cpu),
                mean_millis=round(mean, 3),
                std_millis=round(std, 3),
                source="fitted",
            )
        )
    error = None
    if len(points) >= 3:
        ends = [points[0], points[-1]]
        error = max(
            abs(_between(ends, m.cpu)[0] - m.mean_ms) / m.mean_ms * 100
            for m in points[1:-1]
            if m.mean_ms > 0
        )
    return Fit(None if error is None else round(error, 2), tuple(rows))


def _between(points: Sequence[Measurement], cpu: float) -> tuple[float, float]:
    """Mean and std at ``cpu``, linear in ``1 / c`` between the measured neighbours of
    ``points`` (sorted by CPU); the nearest end outside them."""
    if cpu <= points[0].cpu:
        return points[0].mean_ms, points[0].std_ms
    if cpu >= points[-1].cpu:
        return points[-1].mean_ms, points[-1].std_ms
    hi = next(k for k, m in enumerate(points) if m.cpu >= cpu)
    a, b = points[hi - 1], points[hi]
    w = (1 / cpu - 1 / b.cpu) / (1 / a.cpu - 1 / b.cpu)  # 1 at a, 0 at b
    return b.mean_ms + w * (a.mean_ms - b.mean_ms), b.std_ms + w * (a.std_ms - b.std_ms)


def with_profiled_rows(
    module: SoftwareModule, rows: Iterable[ProfiledRow], profiled_types: Iterable[str]
) -> SoftwareModule:
    """``module`` with the profiled rows of ``profiled_types`` (runs of its current spec)
    appended to its profile, where it declares no rows of that type."""
    declared = {r.hardware_type for r in module.spec.profile}
    use = set(profiled_types) - declared
    extra = [
        ProfileEntry(
            hardware_type=r.hardware_type,
            cpu=r.cpu,
            mean_millis=r.mean_millis,
            std_millis=r.std_millis,
        )
        for r in rows
        if r.hardware_type in use
    ]
    if not extra:
        return module
    spec = module.spec.model_copy(update={"profile": [*module.spec.profile, *extra]})
    return module.model_copy(update={"spec": spec})


def with_profiled_dnn(
    module: SoftwareModule, measured: Iterable[DnnHardwareProfile], profiled_types: Iterable[str]
) -> SoftwareModule:
    """A split network with the profiles ``measured`` on ``profiled_types`` (runs of its current
    spec) in ``spec.dnn.profiles``, where it declares none of that type."""
    dnn = module.spec.dnn
    assert dnn is not None
    declared = {p.hardware_type for p in dnn.profiles}
    use = set(profiled_types) - declared
    extra = [p for p in measured if p.hardware_type in use]
    if not extra:
        return module
    new_dnn = dnn.model_copy(update={"profiles": [*dnn.profiles, *extra]})
    spec = module.spec.model_copy(update={"dnn": new_dnn})
    return module.model_copy(update={"spec": spec})


def current_rows(
    status: ProfilingStatus | None, spec_hash: str
) -> tuple[set[str], list[ProfiledRow]]:
    """The hardware types whose profiling of this spec finished, and their rows."""
    if status is None:
        return set(), []
    done = {
        r.hardware_type for r in status.runs if r.state == "Profiled" and r.spec_hash == spec_hash
    }
    return done, [r for r in status.rows if r.hardware_type in done]


def profiling_status(raw: Mapping[str, Any]) -> ProfilingStatus | None:
    """A SoftwareModule's ``status.profiling`` as the operator wrote it (else None)."""
    return status_part(raw, "profiling", ProfilingStatus)


def with_profiled(module: SoftwareModule, raw: Mapping[str, Any]) -> SoftwareModule:
    """``module`` with the rows its profiling found for its current spec (from ``raw``'s
    status) in its profile, where it declares none of that hardware type."""
    if not auto_profiled(module.spec):
        return module
    status = profiling_status(raw)
    done, rows = current_rows(status, module_spec_hash(module))
    if module.spec.dnn is not None:
        return with_profiled_dnn(module, status.dnn if status else [], done)
    return with_profiled_rows(module, rows, done)
