"""What an offloaded module falls back to when its robot loses the link (issue 13).

RoboEC2 (roboec2-dnn-offloading) keeps a local path that works while the robot is
disconnected; a robot cut off from the edge cannot reach the API server either, so fogfleet
plans the fallback with the placement: with ``mode: onboard`` the robot always holds the
module's on-board share, or the smaller ``cpu`` given (the planner reserves it, as a
constraint), and while the module runs
off board a standby on the robot relays its outputs and computes them itself when they go
silent for ``silentCycles`` cycles, handing back once the remote has delivered for
``stepBackCycles`` cycles. With ``mode: variant`` the standby runs another SoftwareModule, a
lighter variant of the module (a smaller DNN, a lower rate) with its own container, profile
and cycle time, and the robot holds that variant's share instead.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, ClassVar

from pydantic import Field, model_validator

from .base import FogModel, Quantity, parse_cpu
from .common import Name
from .rules import CrossFieldRule, enforce

__all__ = ["STANDING_BY", "Fallback", "FallbackMode"]


class FallbackMode(StrEnum):
    """none: the module stops with the link; onboard: a standby on the robot takes over;
    variant: a standby running a lighter variant module takes over."""

    NONE = "none"
    ONBOARD = "onboard"
    VARIANT = "variant"


STANDING_BY = (FallbackMode.ONBOARD, FallbackMode.VARIANT)  # modes that keep a standby


class Fallback(FogModel):
    """The fallback of an offloaded module when its robot's link fails."""

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "!has(self.mode) || self.mode != 'variant' || has(self.variant)",
            "variant: mode variant needs the name of the SoftwareModule the standby runs",
            lambda f: f.mode is not FallbackMode.VARIANT or f.variant is not None,
        ),
        CrossFieldRule(
            "!has(self.variant) || (has(self.mode) && self.mode == 'variant')",
            "variant: only with mode variant",
            lambda f: f.variant is None or f.mode is FallbackMode.VARIANT,
        ),
    )

    mode: FallbackMode | None = None
    """none, onboard or variant. On a SoftwareModule, unset takes the fleet's (default none)."""
    silent_cycles: Annotated[int, Field(ge=1, le=1000)] = 3
    """Cycles without an output of the remote instance before the standby takes over."""
    step_back_cycles: Annotated[int, Field(ge=1, le=10000)] = 10
    """Cycles the remote instance must deliver without a gap before the standby hands back."""
    cpu: Quantity | None = None
    """CPU the standby runs with on the robot: the largest profiled CPU of the robot's
    hardware at or below it (the smallest profiled one if none is). Unset: the module's own
    on-board share (the variant's largest profiled CPU, with mode variant). Less holds less
    on the robot and
    misses more while its link is down (status.fallbacks predicts how much)."""
    variant: Name | None = None
    """mode variant: the SoftwareModule (same namespace) the standby runs, a lighter variant
    of this one (a smaller DNN, a lower rate) with its own container, profile and
    cycleTimeMillis. It must publish every topic this module publishes; it need not be in
    the fleet."""

    @model_validator(mode="after")
    def _check(self) -> Fallback:
        enforce(self, self.RULES)
        if self.cpu is not None and parse_cpu(self.cpu) <= 0:
            raise ValueError("cpu: must be greater than zero")
        return self
