"""Which module instances keep an on-board fallback in a fleet (issue 13): one rule, used by
the planner (the robot's reserve, ``Problem.fallback``) and by the renderer (the standby).

With ``mode: onboard`` the standby runs the module itself, with a row of the module's own
profile at home. With ``mode: variant`` it runs another SoftwareModule, a lighter variant (a
smaller DNN, a lower rate): that module's profile at the robot's hardware type, its cycle
time, memory and GPUs. RoboEC2 (roboec2-dnn-offloading) keeps such a lighter local path for
when the network fails.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.base import parse_cpu, parse_memory
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.fallback import STANDING_BY, Fallback, FallbackMode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, RobotFleetSpec
from fogfleet.api.v1alpha1.softwaremodule import (
    Scope,
    SoftwareModule,
    SoftwareModuleSpec,
    must_run_on_board,
)
from fogfleet.errors import DanglingReference, InvalidSpec

from .checks import capacity_of
from .dnnpairs import kind_of, robot_row
from .pairs import profile_rows
from .problem import F64, Instance, freeze
from .rows import ProfileRow

__all__ = [
    "Standbys",
    "effective_fallback",
    "fleet_fallbacks",
    "standbys",
    "variant_names",
    "variant_of",
]


def effective_fallback(module: SoftwareModuleSpec, fleet: RobotFleetSpec) -> Fallback | None:
    """The fallback the module's instances keep in this fleet, or None.

    The module's own ``fallback`` wins over the fleet's; its mode, if unset, comes from the
    fleet. Only a per-robot module that publishes (the standby watches its outputs) and may
    leave its robot has one: a module that must run on board (III-B) never runs elsewhere.
    """
    own = module.fallback
    source = own if own is not None else fleet.fallback
    mode = own.mode if own is not None and own.mode is not None else fleet.fallback.mode
    if mode not in STANDING_BY:
        return None
    if module.scope is Scope.SHARED or not module.topics.publishes:
        return None
    if must_run_on_board(module.taxonomy):
        return None
    return Fallback(
        mode=mode,
        silent_cycles=source.silent_cycles,
        step_back_cycles=source.step_back_cycles,
        cpu=source.cpu,
        variant=source.variant if mode is FallbackMode.VARIANT else None,
    )


def fleet_fallbacks(
    fleet: RobotFleetSpec, modules: Mapping[str, SoftwareModule]
) -> dict[str, Fallback]:
    """Module name -> its effective fallback, for the modules that keep one."""
    out: dict[str, Fallback] = {}
    for name, module in modules.items():
        got = effective_fallback(module.spec, fleet)
        if got is not None:
            out[name] = got
    return out


def variant_names(fleet: RobotFleetSpec, modules: Mapping[str, SoftwareModule]) -> set[str]:
    """The variant modules the fleet's modules fall back to (a change to one re-plans it)."""
    wanted = {m.name for m in fleet.modules}
    return {
        fb.variant
        for name, fb in fleet_fallbacks(fleet, modules).items()
        if name in wanted and fb.variant is not None
    }


def variant_of(module: SoftwareModule, fallback: Fallback, catalog: Catalog) -> SoftwareModule:
    """The SoftwareModule a ``mode: variant`` standby runs, checked: it exists in the module's
    namespace, is not the module itself, and publishes every topic the module publishes (the
    robot's consumers must not notice which one answers)."""
    assert fallback.variant is not None
    ns = module.metadata.namespace or "default"
    obj = f"SoftwareModule/{module.metadata.name}"
    if fallback.variant == module.metadata.name:
        raise InvalidSpec(obj, "spec.fallback.variant", "must name another SoftwareModule")
    variant = catalog.module(ns, fallback.variant)
    if variant is None:
        raise DanglingReference(
            obj, "spec.fallback.variant", f"SoftwareModule {ns}/{fallback.variant} does not exist"
        )
    missing = sorted(
        {t.name for t in module.spec.topics.publishes}
        - {t.name for t in variant.spec.topics.publishes}
    )
    if missing:
        raise InvalidSpec(
            obj,
            "spec.fallback.variant",
            f"{fallback.variant} does not publish {', '.join(missing)}: a variant must publish "
            "every topic the module publishes",
        )
    return variant


@dataclass(frozen=True)
class Standbys:
    """What the robots hold for their modules' standbys (``Problem.fallback*``)."""

    keep: NDArray[np.bool_] | None  # (I,) keeps a fallback
    row: F64 | None  # (I, 3) cpu, mean, std the standby runs with at home
    variant: NDArray[np.bool_] | None = None  # (I,) the standby runs a variant module
    cycle: F64 | None = None  # (I,) the standby's cycle time (s)
    need: F64 | None = None  # (I, 2) memory bytes, gpus the standby holds


def standbys(
    fleet: RobotFleet,
    catalog: Catalog,
    modules: Sequence[tuple[SoftwareModule, float, float, int]],
    instances: Sequence[Instance],
    home: Sequence[int],
    robots: Sequence[ComputeNode],
    allowed: NDArray[np.bool_],
    lim: tuple[F64, F64, F64],
    home_rungs: Mapping[int, tuple[ProfileRow, ...]],
) -> Standbys:
    """Which instances keep an on-board fallback (``domain.fallback``) and what their standby
    runs with at home: the largest rung at or below ``fallback.cpu``, else the smallest; the
    limits pick when no cpu is given. A module's own standby runs only where its robot may
    run the module; a variant's where the robot has a profile of the variant."""
    chosen = {m.metadata.name: (m, effective_fallback(m.spec, fleet.spec)) for m, *_ in modules}
    split = {m.metadata.name: (m, c) for m, c, *_ in modules if m.spec.dnn is not None}
    if not any(fb for _, fb in chosen.values()) and not split:
        return Standbys(None, None)
    variants = {
        name: variant_of(m, fb, catalog)
        for name, (m, fb) in chosen.items()
        if fb is not None and fb.mode is FallbackMode.VARIANT
    }
    n = len(instances)
    keep = np.zeros(n, dtype=bool)
    row = np.zeros((n, 3))
    is_variant = np.zeros(n, dtype=bool)
    cycle = np.array([next(c for m, c, *_ in modules if m.metadata.name == inst.module)
                      for inst in instances]) if instances else np.zeros(0)  # fmt: skip
    need = np.zeros((n, 2))
    for i, inst in enumerate(instances):
        mod, fb = chosen.get(inst.module, (None, None))
        h = home[i]
        if inst.module in split and h >= 0:
            # a split network's head and local model stay on its robot (DNNSPLIT.md 3.2): held
            # there like a variant standby, whatever the plan
            net, net_cycle = split[inst.module]
            held = robot_row(net, net_cycle, kind_of(robots[h]), capacity_of(robots[h])[0])
            if held is not None:
                keep[i] = is_variant[i] = True
                row[i] = (held.cpu, held.mean, held.std)
                need[i] = (parse_memory(net.spec.resources.memory), float(net.spec.resources.gpu))
            continue
        if mod is None or fb is None or h < 0:
            continue
        variant = variants.get(inst.module)
        if variant is not None:
            rungs = tuple(profile_rows(variant, robots[h]))
            if not rungs:
                raise InvalidSpec(
                    f"SoftwareModule/{mod.metadata.name}",
                    "spec.fallback.variant",
                    f"{variant.metadata.name} has no profile row for hardware type "
                    f"{robots[h].spec.hardware_type} (robot {robots[h].metadata.name}) nor a "
                    "default row: its standby could not run there",
                )
            cycle[i] = variant.spec.cycle_seconds
            need[i] = (
                parse_memory(variant.spec.resources.memory),
                float(variant.spec.resources.gpu),
            )
            is_variant[i] = True
        elif not allowed[i, h]:
            continue
        else:
            pick = ProfileRow(float(lim[0][i, h]), float(lim[1][i, h]), float(lim[2][i, h]))
            rungs = home_rungs.get(i) or (pick,)
        keep[i] = True
        want = np.inf if fb.cpu is None else parse_cpu(fb.cpu)
        fits = [r for r in rungs if r.cpu <= want + 1e-9]
        best = max(fits, key=lambda r: r.cpu) if fits else min(rungs, key=lambda r: r.cpu)
        row[i] = (best.cpu, best.mean, best.std)
    if not is_variant.any():
        return Standbys(freeze(keep), freeze(row))
    return Standbys(freeze(keep), freeze(row), freeze(is_variant), freeze(cycle), freeze(need))
