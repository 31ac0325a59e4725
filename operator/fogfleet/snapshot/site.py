"""A site of several fleets planned as one: every fleet plans into the room the fleets planned
before it left, in one order, so every command that plans a folder (``plan``, ``render``,
``simulate``, ``explain``) gives each instance the same node and CPU and each fleet the same
refusal. After kueue's ``pkg/scheduler/scheduler.go`` ``schedule()``: numbered steps over one
snapshot of the site."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.domain.tenancy import Held, claims_of
from fogfleet.scheduling.schedule import Schedule

from .problem import problem_of
from .room import room_note
from .snapshot import FleetSnapshot, snapshot_of_catalog

__all__ = ["SitePlan", "plan_site"]

SettingsFor = Callable[[RobotFleet], SchedulerSettings]
Solve = Callable[[Problem, SchedulerSettings], Schedule]


@dataclass(frozen=True)
class SitePlan:
    """One fleet's plan on the site: its snapshot, its problem as built and as planned (a
    degraded plan's CPU amounts), the schedule and the settings it ran with."""

    snapshot: FleetSnapshot
    built: Problem
    problem: Problem
    schedule: Schedule
    settings: SchedulerSettings

    @property
    def name(self) -> str:
        return self.snapshot.name

    @property
    def room(self) -> str:
        """What the other fleets of the site hold on this fleet's nodes, in cores ("": none)."""
        return room_note(self.built, self.snapshot.held)


def plan_site(
    catalog: Catalog,
    fleets: Sequence[RobotFleet],
    settings_for: SettingsFor,
    solve: Solve,
    last: int | None = None,
) -> list[SitePlan]:
    """Plan ``fleets`` (to index ``last``: what comes after cannot change them) as one site."""
    held: dict[str, Held] = {}
    plans: list[SitePlan] = []
    for fleet in fleets[: None if last is None else last + 1]:  # 1. the folder's order
        # 2. the fleet's snapshot: the catalog less what the fleets before it hold
        snapshot = snapshot_of_catalog(catalog, fleet, held)
        # 3. its problem, built the one way (``problem_of``)
        built = problem_of(snapshot)
        # 4. its plan; a degraded plan's CPU amounts and predictions hold for the degraded
        # problem
        settings = settings_for(fleet)
        schedule = solve(built, settings)
        problem = built.with_levels(schedule.levels)
        # 5. what it claims: the room the fleets after it plan around
        claims = claims_of(problem, schedule.placement, schedule.with_limits)
        for node, (cpu, mem) in claims.items():
            held[node] = held.get(node, Held()).plus(cpu, mem, f"RobotFleet {snapshot.name}")
        plans.append(SitePlan(snapshot, built, problem, schedule, settings))
    return plans
