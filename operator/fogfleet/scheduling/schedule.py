"""The scheduling core's output: one chosen plan, its objective values and why it was chosen."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Budget", "Clock", "Schedule"]

# Seconds on a monotonic clock (``time.perf_counter`` in production). The planners read their
# time budget and durations from it; tests pass a clock they advance themselves, so whether a
# budget cuts a search never depends on how fast or loaded the machine is.
Clock = Callable[[], float]


@dataclass
class Budget:
    """A planning budget of ``seconds`` from ``start`` on ``clock``, shared out among the
    search's stages: each stops once ``clock()`` passes its share of it (``over``), and
    ``cut`` records the stages it stopped, in order."""

    clock: Clock
    start: float
    seconds: float = math.inf
    cut: list[str] = field(default_factory=list)

    def ends(self, share: float) -> float:
        """The ``clock()`` value at which a stage given ``share`` of the budget stops."""
        return self.start + share * self.seconds

    def fits(self, stage: str, share: float, seconds: float) -> bool:
        """Whether ``stage``, expected to take about ``seconds`` and not cut finely, ends
        within ``share`` of the budget if it starts now; when not it is recorded as cut."""
        if self.clock() + seconds <= self.ends(share):
            return True
        if stage not in self.cut:
            self.cut.append(stage)
        return False

    def over(self, stage: str, share: float) -> bool:
        """Whether ``stage``, given ``share`` of the budget, must stop now (recorded once)."""
        return not self.fits(stage, share, 0.0)


@dataclass(frozen=True)
class Schedule:
    """A placement of every instance of a Problem.

    ``placement[i]`` is a node index (``-1``: instance ``i`` could not be placed, see
    ``reasons``). ``with_limits`` tells which Allocation of the Problem the plan uses: True for
    fogfleet's own plans (requests = limits per hardware type), False for plans that mimic plain
    Deployments (k8s-default, onboard). A degraded plan's ``levels`` say how far down its
    ladder each instance's CPU was taken.
    """

    scheduler: str
    placement: NDArray[np.int64]
    with_limits: bool
    objectives: dict[str, float]
    feasible: bool
    duration_seconds: float
    choice_reason: str = ""
    pareto_front: NDArray[np.float64] | None = None  # (K, n_obj) objective values of the front
    pareto_placements: NDArray[np.int64] | None = None  # (K, I) the front's plans, same rows
    objective_names: tuple[str, ...] = ()
    reasons: dict[int, str] = field(default_factory=dict)
    generations: int = 0
    evaluations: int = 0
    levels: NDArray[np.int64] | None = None  # (I,) rungs each instance was degraded (degrade)
    # the time budget cut the search short (not: it converged, or ran every generation)
    time_budget_reached: bool = False
    budget_cut: tuple[str, ...] = ()  # the stages it cut, in order ("evolution", "levelling")
    # the robot bound under the fleet's exact weights, where the search priced a plan with it
    # (``configurations.with_priced``): the plan's gap then needs no second computation
    robot_bound: float | None = None

    @property
    def degraded_instances(self) -> int:
        """How many instances run below the CPU their deadline needs (``scheduling.degrade``);
        ``Problem.with_levels(levels)`` is the problem the plan's figures hold for."""
        return int((self.levels > 0).sum()) if self.levels is not None else 0

    @property
    def degraded(self) -> bool:
        return self.degraded_instances > 0
