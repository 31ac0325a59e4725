"""How a fleet watches its robots' links, and what it reports of them (issue 13).

A robot's link is measured from what Prometheus sees of the robot's pods across it: the share
of scrapes answered and the fastest answered scrape of a window (one round trip plus the
exporter's own time). A link measured worse than its ComputeNode's figures is re-planned
around with the measured figures; a link with no answer at all is lost, and then only the
on-board standbys act (a robot cut off cannot receive new pods either). Modules move back
after the link has been healthy for ``stableSeconds``.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

from pydantic import Field

from .base import FogModel, Number

__all__ = ["LinkHealth", "LinkState", "RobotLinkStatus"]


class LinkState(StrEnum):
    """Healthy: as declared. Degraded: measured worse, planned with the measured figures.
    Recovering: healthy again, still planned with the measured figures until stable. Lost: no
    answer at all (the standbys take over; nothing is moved). Unknown: nothing to measure."""

    HEALTHY = "Healthy"
    DEGRADED = "Degraded"
    RECOVERING = "Recovering"
    LOST = "Lost"
    UNKNOWN = "Unknown"


class LinkHealth(FogModel):
    """Measure each robot's link and re-plan its modules when it is worse than declared
    (needs the operator's Prometheus, FOGFLEET_PROMETHEUS_URL)."""

    monitor: bool = True
    """Measure the robots' links and re-plan around bad ones."""
    window_seconds: Annotated[int, Field(ge=5, le=3600)] = 30
    """Measurement window: scrapes answered and the fastest round trip over this long."""
    latency_factor: Number = 3
    """A link is degraded when its measured one-way latency exceeds this many times the
    declared latencyMillis, plus latencyMarginMillis."""
    latency_margin_millis: Number = 20
    """Added to the latency limit (the exporter's own time and the host's scheduling noise)."""
    min_answered_percent: Annotated[int, Field(ge=1, le=100)] = 50
    """A link with fewer answered scrapes than this (but some) is degraded; none: lost."""
    stable_seconds: Annotated[int, Field(ge=0, le=86400)] = 120
    """A degraded link must be measured healthy this long before its modules move back."""


class RobotLinkStatus(FogModel):
    """One robot's link as last measured (fleets whose links are monitored)."""

    robot: str
    """The robot's ComputeNode."""
    state: LinkState
    """Healthy, Degraded, Recovering, Lost or Unknown."""
    declared_latency_millis: float
    """One-way latency its ComputeNode declares."""
    measured_latency_millis: float | None = None
    """One-way latency measured (half the fastest answered scrape of the window)."""
    answered_percent: float | None = None
    """Share of its pods' scrapes answered in the window."""
    planned_latency_millis: float | None = None
    """One-way latency the plan uses, when not the declared one (Degraded, Recovering)."""
    since: str | None = None
    """When the link entered this state (RFC 3339)."""
    standbys_active: list[str] = Field(default_factory=list)
    """Modules whose on-board standby computes their outputs now (fogfleet_fallback_active)."""
    message: str = ""
    """Why, in words."""
