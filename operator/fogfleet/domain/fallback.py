"""Which module instances keep an on-board fallback in a fleet (issue 13): one rule, used by
the planner (the robot's reserve, ``Problem.fallback``) and by the renderer (the standby)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, RobotFleetSpec
from fogfleet.api.v1alpha1.softwaremodule import (
    Scope,
    SoftwareModule,
    SoftwareModuleSpec,
    must_run_on_board,
)

from .pairs import ProfileRow
from .problem import F64, Instance, freeze

__all__ = ["effective_fallback", "fleet_fallbacks", "standby_rows"]


def effective_fallback(module: SoftwareModuleSpec, fleet: RobotFleetSpec) -> Fallback | None:
    """The fallback the module's instances keep in this fleet, or None.

    The module's own ``fallback`` wins over the fleet's; its mode, if unset, comes from the
    fleet. Only a per-robot module that publishes (the standby watches its outputs) and may
    leave its robot has one: a module that must run on board (III-B) never runs elsewhere.
    """
    own = module.fallback
    source = own if own is not None else fleet.fallback
    mode = own.mode if own is not None and own.mode is not None else fleet.fallback.mode
    if mode is not FallbackMode.ONBOARD:
        return None
    if module.scope is Scope.SHARED or not module.topics.publishes:
        return None
    if must_run_on_board(module.taxonomy):
        return None
    return Fallback(
        mode=FallbackMode.ONBOARD,
        silent_cycles=source.silent_cycles,
        step_back_cycles=source.step_back_cycles,
        cpu=source.cpu,
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


def standby_rows(
    fleet: RobotFleet,
    modules: Sequence[tuple[SoftwareModule, float, float, int]],
    instances: Sequence[Instance],
    home: Sequence[int],
    allowed: NDArray[np.bool_],
    lim: tuple[F64, F64, F64],
    home_rungs: Mapping[int, tuple[ProfileRow, ...]],
) -> tuple[NDArray[np.bool_] | None, F64 | None]:
    """Which instances keep an on-board fallback (``domain.fallback``; only where the robot
    may run the module: the standby runs there) and the profile row their standby runs with
    at home: the largest rung at or below ``fallback.cpu``, else the smallest; the limits
    pick when no cpu is given."""
    chosen = {m.metadata.name: effective_fallback(m.spec, fleet.spec) for m, *_ in modules}
    if not any(chosen.values()):
        return None, None
    keep = np.zeros(len(instances), dtype=bool)
    row = np.zeros((len(instances), 3))
    for i, inst in enumerate(instances):
        fb, h = chosen.get(inst.module), home[i]
        if fb is None or h < 0 or not allowed[i, h]:
            continue
        keep[i] = True
        pick = ProfileRow(float(lim[0][i, h]), float(lim[1][i, h]), float(lim[2][i, h]))
        rungs = home_rungs.get(i) or (pick,)
        want = np.inf if fb.cpu is None else parse_cpu(fb.cpu)
        fits = [r for r in rungs if r.cpu <= want + 1e-9]
        best = max(fits, key=lambda r: r.cpu) if fits else min(rungs, key=lambda r: r.cpu)
        row[i] = (best.cpu, best.mean, best.std)
    return freeze(keep), freeze(row)
