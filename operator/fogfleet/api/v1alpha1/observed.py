"""What runs teaches the planner (issue 10): measured execution times, the correction of a
module's declared profile they lead to, and when a fleet re-plans for it.

The declared profile (``SoftwareModule.spec.profile``) is the prior. The operator reads each
module's measured execution times from Prometheus (``fogfleet_execution_time_seconds`` by
hardware type and CPU limit) into ``status.observed``. When a fleet's modules miss more
cycles than its plan predicted (``spec.drift``), the operator blends the observations into a
correction per hardware type (``status.profileCorrection``: a factor on the execution times
and the cycle's noise) and the fleet is planned with the declared rows so corrected.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from .base import FogModel, Number

__all__ = ["DriftSettings", "ObservedRow", "ProfileCorrection"]


class DriftSettings(FogModel):
    """When a fleet is re-planned because its modules miss more than predicted (needs the
    operator's Prometheus, FOGFLEET_PROMETHEUS_URL)."""

    enabled: bool = True
    """Watch the measured miss rates and re-plan with learnt profiles on drift."""
    window_seconds: Annotated[int, Field(ge=10, le=86400)] = 120
    """Window of the measured miss rates and execution times."""
    margin_percent: Number = 5
    """Drift: a module's measured miss rate above its predicted one by more than its
    real-time class affords: this many percentage points for soft real-time, a hundredth of
    it for hard real-time or safety-critical (a missed deadline is a failure there), twice it
    for the rest."""
    for_seconds: Annotated[int, Field(ge=0, le=86400)] = 60
    """... for at least this long (a passing burst is not drift)."""
    min_interval_seconds: Annotated[int, Field(ge=0, le=86400)] = 300
    """At least this long between two re-plans of the fleet for drift (no flapping)."""
    prior_cycles: Annotated[int, Field(ge=0, le=1000000)] = 100
    """Weight of the declared profile in the blend, as a number of measured cycles: the
    correction is (prior x 1 + n x measured/declared) / (prior + n)."""
    min_cycles: Annotated[int, Field(ge=0, le=100000000)] = 1000
    """Cycles measured on a hardware type before the cycle noise learnt there counts (fewer:
    the prior, no noise). A noise is fitted to a tail, and a few misses in a few hundred cycles
    move modules on luck; the factor is not held back by it."""


class ObservedRow(FogModel):
    """A module's execution times as measured on one hardware type with one CPU limit."""

    hardware_type: str
    """The node's hardware type."""
    cpu: str
    """The CPU limit the module ran with ("100m"; empty without a limit)."""
    count: float
    """Cycles measured in the window."""
    mean_millis: float
    """Mean execution time, in milliseconds."""
    std_millis: float
    """Standard deviation, in milliseconds ((p95 - mean) / 1.645: normal tails)."""
    p95_millis: float
    """95th percentile, in milliseconds (from the histogram's buckets)."""
    declared_mean_millis: float | None = None
    """The declared profile's mean for this hardware type and CPU, in milliseconds."""
    cycles: float | None = None
    """Cycles the module ran here in the window (its work and everything around it)."""
    missed_percent: float | None = None
    """Share of those cycles longer than the module's cycle time, in percent."""
    last_update: str
    """When it was measured (RFC 3339)."""


class ProfileCorrection(FogModel):
    """What the planner multiplies a module's declared profile by on one hardware type."""

    hardware_type: str
    """The hardware type."""
    factor: float
    """Measured over declared execution time, blended with the prior (1: as declared)."""
    noise_millis: float = 0.0
    """Standard deviation of what a cycle takes besides its work and transfer (wake-ups,
    middleware, the node's other processes), in milliseconds: fitted so that the planner's
    normal tail at the deadline matches the measured miss rate, blended with the prior (0),
    and added to every row's std on this hardware type."""
    noise_cycles: float = 0.0
    """Cycles the noise was fitted from (spec.drift.minCycles or more); 0 with no noise: not
    known on this hardware type, and the planner takes the largest noise the module showed on
    another type instead (no move gains from a noise that was only not measured)."""
    samples: float
    """Measured cycles behind it."""
    adopted_at: str
    """When a fleet's drift made the planner adopt it (RFC 3339)."""
    reason: str = ""
    """The drift that led to it."""
