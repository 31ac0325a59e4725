"""The render steps, pure: the fleet's ROS 2 wiring objects (``wiring_step``) and its modules'
Deployments from its decision (``render_step``), given the wiring as applied (the discovery
Services' cluster IPs go into every module's ``ROS_DISCOVERY_SERVER``).

The wiring is rendered after planning: an infeasible fleet gets nothing applied, not even its
discovery servers.
"""

from __future__ import annotations

from typing import Any

from fogfleet.controllers.fleet.observe import FleetInputs, Parsed
from fogfleet.controllers.fleet.plan import Planned
from fogfleet.domain.fallback import fleet_fallbacks
from fogfleet.render.deployments import render_fleet
from fogfleet.render.ros import RosWiring
from fogfleet.render.wiring import RosObjects, ros_objects

__all__ = ["render_step", "wiring_step"]

Obj = dict[str, Any]


def wiring_step(inputs: FleetInputs, parsed: Parsed, planned: Planned) -> RosObjects | None:
    """The fleet's discovery servers and NetworkPolicies (None: its ROS wiring is off)."""
    obj = inputs.obj
    return ros_objects(
        inputs.fleet.spec.ros,
        planned.problem,
        obj.owner,
        obj.selector,
        parsed.modules.values(),
    )


def render_step(
    inputs: FleetInputs, parsed: Parsed, planned: Planned, wiring: RosWiring | None
) -> list[Obj]:
    """The Deployments the fleet's modules should have (instance order)."""
    fleet, obj, problem = inputs.fleet, inputs.obj, planned.problem
    modules = parsed.modules
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
