"""The render step: the fleet's desired Deployments from its decision.

The robots' discovery servers are applied first (after planning: an infeasible fleet gets
nothing applied, not even them): their Services' cluster IPs go into every module's
``ROS_DISCOVERY_SERVER``.
"""

from __future__ import annotations

from typing import Any

from fogfleet.domain.fallback import fleet_fallbacks
from fogfleet.render.deployments import render_fleet

from .deps import Deps
from .fleet_plan import Planned
from .observe import FleetInputs, Parsed
from .ros import apply_ros_wiring

__all__ = ["render_step"]

Obj = dict[str, Any]


def render_step(deps: Deps, inputs: FleetInputs, parsed: Parsed, planned: Planned) -> list[Obj]:
    """The Deployments the fleet's modules should have (instance order)."""
    fleet, obj, problem = inputs.fleet, inputs.obj, planned.problem
    modules = parsed.modules
    wiring = apply_ros_wiring(
        deps.kube, fleet, problem, obj.owner, obj.selector, modules.values(), deps.api_concurrency
    )
    decision = planned.decision
    if decision is None:
        return render_fleet(problem, modules, None, baseline=True, owner=obj.owner, wiring=wiring)
    return render_fleet(
        problem,
        modules,
        decision.placement,
        with_limits=decision.schedule.with_limits,
        cpu_limit_percent=fleet.spec.scheduler.cpu_limit_percent,
        fallbacks=fleet_fallbacks(fleet.spec, modules),
        owner=obj.owner,
        plan_id=decision.plan_id,
        wiring=wiring,
    )
