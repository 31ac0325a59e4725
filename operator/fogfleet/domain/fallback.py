"""Which module instances keep an on-board fallback in a fleet (issue 13): one rule, used by
the planner (the robot's reserve, ``Problem.fallback``) and by the renderer (the standby)."""

from __future__ import annotations

from collections.abc import Mapping

from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
from fogfleet.api.v1alpha1.robotfleet import RobotFleetSpec
from fogfleet.api.v1alpha1.softwaremodule import (
    Scope,
    SoftwareModule,
    SoftwareModuleSpec,
    must_run_on_board,
)

__all__ = ["effective_fallback", "fleet_fallbacks"]


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
