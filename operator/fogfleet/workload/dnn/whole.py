"""A split module run whole, as a module that cannot be split runs (``--whole``): the two
whole-module placements ``make bench-split`` measures the split against (issue 48: "versus
whole-module placement on the same bed and links").

- ``edge``: the module placed off-board. Every frame's input crosses the link and the tail's
  node runs the whole network (action 0, full offload, as ``Tail`` answers it); the frame waits
  for that answer however long it takes, with no local model (a module placed on the edge has
  none). An answer that has not come after ``UNANSWERED_AFTER`` alphas is taken as lost.
- ``robot``: the module placed on its robot. The whole network runs on the head's CPU.

The rule is not consulted and nothing is learnt: the frames are counted as the head's are
(``FrameResult``), so a benchmark reads both from the same metrics.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Any, Protocol

from fogfleet.contract.dnn import FULL_OFFLOAD

from .head import By, FrameResult, Head, Mailbox, RobotParts
from .runspec import DnnRunSpec
from .wire import Packet

__all__ = ["UNANSWERED_AFTER", "WHOLE_ON_ROBOT", "Whole", "WholeHead", "WholeParts"]

UNANSWERED_AFTER = 10  # alphas a frame on the edge waits for its answer before it is lost
WHOLE_ON_ROBOT = "whole network on the robot"  # the action's name in the metrics


class Whole(StrEnum):
    """Where the whole network runs."""

    EDGE = "edge"
    ROBOT = "robot"


class WholeParts(RobotParts, Protocol):
    """The robot's networks with the whole one (``sessions.RobotNets``)."""

    def whole(self, frame: Any) -> bytes: ...


class WholeHead(Head):
    """``Head``'s loop and counters, one fixed placement per frame."""

    def __init__(
        self,
        where: Whole,
        run: DnnRunSpec,
        parts: WholeParts,
        send: Callable[[Packet], None],
        clock: Callable[[], float],
        mailbox: Mailbox | None = None,
        cpu_clock: Callable[[], float] | None = None,
    ) -> None:
        super().__init__(run, parts, send, clock, mailbox, cpu_clock)
        self.where, self.whole_parts = where, parts

    def frame(self) -> FrameResult:
        start = self.clock()
        self.count += 1
        n = self.count
        image = self.parts.capture(n)
        if self.where is Whole.ROBOT:
            c0 = self.cpu_clock()
            answer, by, action = self.whole_parts.whole(image), By.ROBOT, WHOLE_ON_ROBOT
            robot_s = self.cpu_clock() - c0
        else:
            self._send_tensor(n, 0, image)
            robot_s = 0.0  # the raw frame: no network runs on the robot
            got = self.mailbox.wait(n, 0, start + UNANSWERED_AFTER * self.decider.alpha)
            answer, by = (b"", By.UNANSWERED) if got is None else (got[0].payload, By.TAIL)
            action = FULL_OFFLOAD
        return FrameResult(
            frame=n,
            action=action,
            by=by,
            answer=answer,
            started=start,
            predicted_s=float("nan"),
            real_s=self.clock() - start,
            proposed="",
            reason=f"--whole {self.where.value}: the network whole, the rule not consulted",
            alpha_s=self.decider.alpha,
            robot_s=robot_s,
        )
