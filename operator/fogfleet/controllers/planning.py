"""The controller's Planner: the scheduling core's solver (NSGA-II and the references)."""

from __future__ import annotations

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import plan

__all__ = ["CorePlanner"]


class CorePlanner:
    """Planner over :func:`fogfleet.scheduling.solver.plan`."""

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule:
        return plan(problem, settings)
