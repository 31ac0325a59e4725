"""Automatic profiling of a module that has no profile for a hardware type (issue 10).

Nobody has Fig. 3's look-up table for every module, hardware type and CPU limit.
FogROS2-Config benchmarks a few edge-case machines and fits its latency model from them
instead of benchmarking the whole grid; fogfleet does the same per hardware type: with
``profiling.mode: auto`` a fleet that needs the module on a hardware type without rows gets
short profiling Jobs of the module's own container there, at the smallest, the largest and
one middle CPU limit of ``profiling.cpus``, interpolates the others between what they
measured (``domain.profiling``) and writes every limit of the grid to the module's
``status.profiling.rows`` (measured rows as measured, the others fitted). The fleet is
planned once every profile it needs is known and says what it waits for until then.

The module's container must support the profiling contract (the fogfleet workload does):
with ``FOGFLEET_PROFILE_CYCLES=N`` it runs N cycles of its work alone, at its CPU limit, and
writes one JSON line (``cycles``, ``meanMillis``, ``stdMillis``, ``p95Millis``,
``cpuSeconds``, ...) to its termination message.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import Field, model_validator

from .base import FogModel, Quantity, format_millicores, parse_cpu, refuse_duplicates
from .dnn import DnnHardwareProfile

__all__ = [
    "DEFAULT_PROFILING_CPUS",
    "ProfiledRow",
    "Profiling",
    "ProfilingMode",
    "ProfilingRun",
    "ProfilingStatus",
]

# a grid for a module that names none: the CPU limits robots and edge nodes commonly give
DEFAULT_PROFILING_CPUS: tuple[str | int, ...] = ("50m", "100m", "200m", "400m", "800m")


class ProfilingMode(StrEnum):
    """off: a hardware type without profile rows is not a place for the module; auto: the
    operator profiles the module there with short Jobs before planning it."""

    OFF = "off"
    AUTO = "auto"


class Profiling(FogModel):
    """How the operator profiles the module on a hardware type that has no profile rows."""

    mode: ProfilingMode = ProfilingMode.OFF
    """off (default) or auto."""
    cpus: Annotated[list[Quantity], Field(min_length=1, max_length=16)] = Field(
        default_factory=lambda: list(DEFAULT_PROFILING_CPUS)
    )
    """The CPU limits the planner may give the module (the grid). Jobs measure the smallest,
    the largest and one in between; the rest are fitted. A split network (spec.dnn) runs on
    one thread: one Job per hardware type times it at one core (or the node's whole CPU
    below that), and the grid is not used."""
    cycles: Annotated[int, Field(ge=5, le=10000)] = 50
    """Cycles each profiling Job measures (a split network's: frames timed per part)."""
    timeout_seconds: Annotated[int, Field(ge=30, le=3600)] = 300
    """A profiling Job that has not finished by then has failed."""

    @model_validator(mode="after")
    def _check(self) -> Profiling:
        for k, cpu in enumerate(self.cpus):
            if parse_cpu(cpu) <= 0:
                raise ValueError(f"profiling.cpus[{k}]: must be greater than zero")
        refuse_duplicates([format_millicores(parse_cpu(c)) for c in self.cpus], "profiling.cpus")
        return self


class ProfiledRow(FogModel):
    """One profile row the operator measured or fitted (used like a declared row)."""

    hardware_type: str
    """The hardware type it was profiled on."""
    cpu: str
    """The CPU limit ("100m")."""
    mean_millis: float
    """Mean execution time of one cycle, in milliseconds."""
    std_millis: float
    """Standard deviation, in milliseconds."""
    source: Literal["measured", "fitted"]
    """measured by a profiling Job at this limit, or fitted from the measured ones."""
    cycles: int = 0
    """Cycles measured (0 for a fitted row)."""


class ProfilingRun(FogModel):
    """The profiling of the module on one hardware type."""

    hardware_type: str
    """The hardware type."""
    state: Literal["Running", "Profiled", "Failed"]
    """Running (Jobs under way), Profiled (rows in status.profiled) or Failed."""
    jobs: int
    """Profiling Jobs run (or running) for it."""
    grid: int
    """CPU limits in the grid: the Jobs a full grid would have needed."""
    cpu_seconds: float = 0
    """CPU the profiling Jobs used, in seconds (what they measured of their own work)."""
    wall_seconds: float = 0
    """How long the Jobs ran, added up, in seconds."""
    fit_error_percent: float | None = None
    """How far the fitted rows may be off, in percent: the middle measured limit as the two
    ends predict it, against what it measured (three limits or more)."""
    message: str = ""
    """What happened (the failure's reason)."""
    spec_hash: str
    """The module spec this run profiled (a changed container or grid profiles again)."""
    last_update: str
    """When it last changed (RFC 3339)."""


class ProfilingStatus(FogModel):
    """What automatic profiling found (SoftwareModule status)."""

    runs: list[ProfilingRun] = Field(default_factory=list)
    """One per hardware type profiled."""
    rows: list[ProfiledRow] = Field(default_factory=list)
    """The profile rows found, per hardware type and CPU limit."""
    dnn: list[DnnHardwareProfile] = Field(default_factory=list)
    """A split network's (spec.dnn) times measured per hardware type: every part's time per
    frame and the bytes that cross (used like spec.dnn.profiles)."""
