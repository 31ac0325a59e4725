"""How far the search came from the best any plan could do: the best scalarised S it found,
and the deployed plan's, against a lower bound on every plan's S (``RobotFleet.status.planGap``,
the Planned Event, ``fogfleet bench budget``).

S is ``exact.scalarised``: multi-robot-edge-cloud-scheduling III-B's objectives (miss rate,
missed cycles, F1 on-board use, F4 reserve, and cost) weighted as the exact scheduler weighs
them for the fleet (``exact.fleet_weights``). The bound is the tighter of

- the robot bound (``configurations.robot_bound``: each robot's instances are whole; ~1.5 s at 1000
  robots x 8 modules, where it is 2-4 % above the LP's), where it applies, and
- the LP relaxation's optimum (``exact.lp_bound``), for fleets of at most ``LP_PAIRS``
  (instance, node) pairs (at 1000 robots the LP takes CPU minutes).

A gap is therefore an upper bound on how far an S is from the optimum: part of it may be the
bound's own. The best S found (over the search's Pareto front and the deployed plan) says how
good the search was; the deployed plan is chosen from that front by the fleet's own rule (the
default lexicographic choice puts misses first, not S), so its gap also holds what that rule
traded: on the warehouse example 79 % against the best's few. A degraded plan, a plan with an
unplaced instance and a plan of the nominal allocation (onboard) get none.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible

from .configurations import robot_bound
from .exact import lp_bound, scalarised_plans

__all__ = ["LP_PAIRS", "PlanGap", "plan_gap"]

LP_PAIRS = 5_000  # (instance, node) pairs up to which the LP bound is solved too (~0.1 s)
LP_SECONDS = 5.0  # the LP's time limit; past it the robot bound alone is reported


@dataclass(frozen=True)
class PlanGap:
    """The best S the search found (its front's, or the deployed plan's if lower), the
    deployed plan's S, a lower bound on every plan's S, and which bound it is."""

    value: float  # the best S found
    bound: float
    kind: str  # "robot" (configurations.robot_bound) or "lp" (exact.lp_bound)
    deployed: float  # the deployed plan's S

    @property
    def percent(self) -> float:
        """The best S's gap: how far the search came from the optimum of S, at most."""
        return _above(self.value, self.bound)

    @property
    def deployed_percent(self) -> float:
        """The deployed plan's gap: the search's, plus what the fleet's choice rule traded
        for its own order (a lexicographic choice puts misses first, not S)."""
        return _above(self.deployed, self.bound)

    def describe(self) -> str:
        """The gap as people read it (the Planned Event)."""
        text = (
            f"best S found {self.value:.5g}, {self.percent:.1f} % above the {self.kind} "
            f"bound {self.bound:.5g}"
        )
        if self.deployed > self.value + 1e-12:
            text += f" (the plan chosen by the fleet's rule: S {self.deployed:.5g})"
        return text


def _above(value: float, bound: float) -> float:
    """(value - bound) / bound in percent, never below 0 (a bound within the solver's
    tolerance of S is a gap of 0)."""
    if bound <= 0:
        return 0.0 if value <= bound + 1e-12 else float("inf")
    return max(100.0 * (value - bound) / bound, 0.0)


def plan_gap(
    problem: Problem,
    placement: NDArray[np.integer],
    weights: Mapping[str, float],
    front: NDArray[np.integer] | None = None,
    robot: float | None = None,
) -> PlanGap | None:
    """The gap of ``placement`` (limits allocation) and of the best plan of ``front`` (the
    search's Pareto front, (K, I)) under ``weights``; None where no bound applies or an
    instance with a node is unplaced. ``robot``: the robot bound under ``weights`` where the
    search computed it already (``Schedule.robot_bound``)."""
    x = np.asarray(placement, dtype=np.int64)
    placeable = problem.allowed.any(axis=1)
    if (x[placeable] < 0).any():
        return None
    bounds: list[tuple[float, str]] = []
    whole = robot_bound(problem, weights) if robot is None else robot
    if whole is not None:
        bounds.append((whole, "robot"))
    if int(problem.allowed.sum()) <= LP_PAIRS:
        # stranded instances (no node left) or the time limit: the LP gives no bound
        with contextlib.suppress(Infeasible):
            bounds.append((lp_bound(problem, weights, time_limit=LP_SECONDS), "lp"))
    if not bounds:
        return None
    bound, kind = max(bounds)
    plans = x[None, :]
    if front is not None and len(front):
        found = np.asarray(front, dtype=np.int64)
        plans = np.concatenate([plans, found[~(found[:, placeable] < 0).any(axis=1)]])
    values = scalarised_plans(problem, plans, weights)
    return PlanGap(float(values.min()), bound, kind, float(values[0]))
