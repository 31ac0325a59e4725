"""The head's choice per frame: RoboEC2's rule over what it measured, with hysteresis.

Each frame the rule (``contract.dnnsplit.choose``, the planner's very function; RoboEC2
Algorithm 1: "each time step is independent") is applied to the link the head estimates and
to the parts' measured times (``estimate``). Its answer is a *proposal*: the action the head
runs changes only when another action has been proposed for ``HYSTERESIS_FRAMES`` frames in a
row, except after a cut, when an off-board action has no answer to wait for and the local model
takes over at once (Algorithm 1: disconnected => action n+1), and when the action run now is
estimated to miss alpha (eq. 8's bound: the rule has dropped it, there is nothing to wait for).

Before a probe's echo and a frame's answer have both come back, the link's bandwidth is
unknown: the head runs the plan's action (the planner chose it with the declared table and the
node's declared link), and returns to it after a cut at the start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fogfleet.contract.dnnsplit import Action, Choice, actions, choose

from .estimate import LinkEstimator, PartTimes
from .runspec import DnnRunSpec

__all__ = ["HYSTERESIS_FRAMES", "Decider", "Decision", "Hysteresis"]

# Why 5: DNNSPLIT.md 3.3 saw the rule's choice move near alpha when the machine was busy (head
# times 30-60 % higher for a while), and RoboEC2's Tables II-IV put neighbouring actions within
# a few ms of each other; a proposal must outlive one noisy frame. Five frames is the EWMA's
# memory (estimate.EWMA_WEIGHT = 0.2): a change that lasts that long has mostly replaced the
# estimate it was made from. At 10 Hz it is half a second, well inside issue 48's "the split
# returns after the hysteresis".
HYSTERESIS_FRAMES = 5


@dataclass
class Hysteresis:
    """Keep ``current`` until another action was proposed ``frames`` times in a row."""

    current: int
    frames: int = HYSTERESIS_FRAMES
    streak: int = 0

    def step(self, proposed: int, at_once: bool = False) -> int:
        """The action to run now, given this frame's proposal (``at_once``: no waiting)."""
        if proposed == self.current:
            self.streak = 0
        elif at_once or self.streak + 1 >= self.frames:
            self.current, self.streak = proposed, 0
        else:
            self.streak += 1
        return self.current


@dataclass(frozen=True)
class Decision:
    """The action to run this frame and what the rule said."""

    action: Action
    proposed: Choice | None  # None: nothing known of the link yet (the plan's action)
    predicted_s: float  # Time(a) of the action run, as now estimated (inf: unknown)


class Decider:
    """The head's state for the rule: link and part estimates, cut or not, the hysteresis."""

    def __init__(self, run: DnnRunSpec, frames: int = HYSTERESIS_FRAMES) -> None:
        self.run = run
        self.link = LinkEstimator()
        self.parts = PartTimes(run.model, run.robot_factor, run.tail_factor)
        self.cut = False  # the last probe or answer did not come back within alpha
        self.hysteresis = Hysteresis(run.planned_index, frames)

    @property
    def alpha(self) -> float:
        return self.run.model.max_latency_s

    def candidates(self) -> list[Action]:
        """Every action with this moment's estimates (the link None while cut)."""
        model, robot, tail = self.parts.model_now()
        cands = actions(model, None if self.cut else self.link.link(), robot, tail)
        return self.parts.with_robot_cpu(cands)

    def decide(self) -> Decision:
        """This frame's action. Cut: the rule (the local model, at once if an off-board
        action ran). Up but not yet measured (probes echoed, no answer yet): back to the
        plan's action, with the hysteresis. Measured: the rule, with the hysteresis."""
        cands = self.candidates()
        if not self.cut and self.link.link() is None:
            proposed = self.run.planned_index if self.link.echoed else self.hysteresis.current
            action = cands[self.hysteresis.step(proposed)]
            return Decision(action, None, math.inf if action.offloaded else action.time_s)
        model, _, _ = self.parts.model_now()
        choice = choose(model, cands)
        current = cands[self.hysteresis.current]
        # no waiting when what runs now has no answer to wait for (cut) or would miss alpha
        at_once = (self.cut and current.offloaded) or current.time_s > self.alpha
        action = cands[self.hysteresis.step(choice.action.index, at_once)]
        return Decision(action, choice, action.time_s)
