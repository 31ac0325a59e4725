"""The controller's Planner: the scheduling core's solver (NSGA-II and the references)."""

from __future__ import annotations

from collections.abc import Collection

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.incremental import Replan, replan
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import plan

__all__ = ["CorePlanner"]


class CorePlanner:
    """Planner over :func:`fogfleet.scheduling.solver.plan`."""

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule:
        return plan(problem, settings)

    def replan(
        self,
        problem: Problem,
        settings: SchedulerSettings,
        changed: Collection[int],
        reference: float | None,
    ) -> Replan:
        return replan(problem, settings, changed=changed, reference=reference)
