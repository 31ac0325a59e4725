"""How far a plan is from the best any plan could do: its scalarised S against a lower bound
on every plan's S (``RobotFleet.status.planGap``, the Planned Event, ``fogfleet bench budget``).

S is ``exact.scalarised``: multi-robot-edge-cloud-scheduling III-B's objectives (miss rate,
missed cycles, F1 on-board use, F4 reserve, and cost) weighted as the exact scheduler weighs
them for the fleet (``exact.fleet_weights``). The bound is the tighter of

- the robot bound (``exact.robot_bound``: each robot's instances are whole; ~1.5 s at 1000
  robots x 8 modules, where it is 2-4 % above the LP's), where it applies, and
- the LP relaxation's optimum (``exact.lp_bound``), for fleets of at most ``LP_PAIRS``
  (instance, node) pairs (at 1000 robots the LP takes CPU minutes).

The gap is therefore an upper bound on how far the plan's S is from the optimum: part of it
may be the bound's own. A plan chosen lexicographically (the default: misses first) is not the
plan of least S, so its gap can exceed the search's best; a degraded plan, a plan with an
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

from .exact import lp_bound, robot_bound, scalarised

__all__ = ["LP_PAIRS", "PlanGap", "plan_gap"]

LP_PAIRS = 5_000  # (instance, node) pairs up to which the LP bound is solved too (~0.1 s)
LP_SECONDS = 5.0  # the LP's time limit; past it the robot bound alone is reported


@dataclass(frozen=True)
class PlanGap:
    """A plan's S, a lower bound on every plan's S, and which bound it is."""

    value: float
    bound: float
    kind: str  # "robot" (exact.robot_bound) or "lp" (exact.lp_bound)

    @property
    def percent(self) -> float:
        """(S - bound) / bound in percent, never below 0 (a bound within the solver's
        tolerance of S is a gap of 0)."""
        if self.bound <= 0:
            return 0.0 if self.value <= self.bound + 1e-12 else float("inf")
        return max(100.0 * (self.value - self.bound) / self.bound, 0.0)

    def describe(self) -> str:
        """``S 1.2345, 3.1 % above the robot bound 1.1973``: the gap as people read it."""
        return (
            f"S {self.value:.5g}, {self.percent:.1f} % above the {self.kind} bound {self.bound:.5g}"
        )


def plan_gap(
    problem: Problem, placement: NDArray[np.integer], weights: Mapping[str, float]
) -> PlanGap | None:
    """The gap of ``placement`` (limits allocation) under ``weights``, or None where no bound
    applies or an instance with a node is unplaced."""
    x = np.asarray(placement, dtype=np.int64)
    if (x[problem.allowed.any(axis=1)] < 0).any():
        return None
    bounds: list[tuple[float, str]] = []
    whole = robot_bound(problem, weights)
    if whole is not None:
        bounds.append((whole, "robot"))
    if int(problem.allowed.sum()) <= LP_PAIRS:
        # stranded instances (no node left) or the time limit: the LP gives no bound
        with contextlib.suppress(Infeasible):
            bounds.append((lp_bound(problem, weights, time_limit=LP_SECONDS), "lp"))
    if not bounds:
        return None
    bound, kind = max(bounds)
    return PlanGap(scalarised(problem, x, weights), bound, kind)
