"""The objective registry: every objective a RobotFleet may name in ``spec.scheduler.objectives``,
with what it measures.

One entry per objective: its wire name (``ObjectiveName``, the CRD's enum), where it comes
from (F1-F4 of multi-robot-edge-cloud-scheduling, eq. 1-6, or an extension), its label and
unit for people, its direction and the resolution below which two values are the same to the
search; then which objectives are *miss* objectives (the lexicographic choice leads with
those and applies its soft rules, preferred tiers then cost, right after them) and the
default list.

The functions that compute them live one layer up, in ``scheduling.objectives``, keyed by
these names; it refuses to import if an objective here has no function there or the other
way round.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = [
    "DEFAULT_OBJECTIVES",
    "MISS_OBJECTIVES",
    "OBJECTIVE_SPECS",
    "Direction",
    "ObjectiveName",
    "ObjectiveSpec",
]


class ObjectiveName(StrEnum):
    """F1-F4 of multi-robot-edge-cloud-scheduling (eq. 1-6) plus the extensions."""

    ONBOARD = "onboard"  # F1, eq. 1
    RESERVE = "reserve"  # F2, eq. 2
    BALANCE = "balance"  # F3, eq. 3
    MISSED_CYCLES = "missedCycles"  # F4, eq. 6
    MISS_RATE = "missRate"  # predicted fraction of missed cycles
    COST = "cost"
    ENERGY = "energy"
    MIGRATIONS = "migrations"  # instances a plan moves off the node they run on (issue 10)


class Direction(StrEnum):
    """Which way an objective improves. The search minimises every column of F, so an
    objective to maximise must be negated by its function (none is today)."""

    MINIMISE = "minimise"
    MAXIMISE = "maximise"


@dataclass(frozen=True)
class ObjectiveSpec:
    """What one objective measures (its function: ``scheduling.objectives.REGISTRY``)."""

    name: ObjectiveName
    label: str  # for people: tables, reports
    unit: str  # of its value
    source: str  # the paper's objective and equation, or the extension
    direction: Direction = Direction.MINIMISE
    resolution: float = 0.0  # differences below this are noise to the search (0: none)


_SPECS = (
    ObjectiveSpec(
        ObjectiveName.ONBOARD,
        "on-board resource use",
        "sum of robot utilisations (cpu + memory)",
        "F1, eq. 1",
        resolution=1e-4,
    ),
    ObjectiveSpec(
        ObjectiveName.RESERVE,
        "peak requested utilisation",
        "fraction of a node's limit",
        "F2, eq. 2",
        resolution=1e-4,
    ),
    ObjectiveSpec(
        ObjectiveName.BALANCE,
        "utilisation spread within each tier",
        "sum of standard deviations of utilisation",
        "F3, eq. 3",
        resolution=1e-4,
    ),
    ObjectiveSpec(
        ObjectiveName.MISSED_CYCLES,
        "activation-weighted cycle overrun",
        "sum of activation x tau over instances with tau > 1",
        "F4, eq. 5-6",
        resolution=1e-4,
    ),
    ObjectiveSpec(
        ObjectiveName.MISS_RATE,
        "predicted miss rate",
        "fraction of cycles (mean over modules)",
        "extension: predicted share of missed cycles",
        resolution=1e-5,
    ),
    ObjectiveSpec(
        ObjectiveName.COST,
        "cost of requested cores",
        "cost per hour",
        "extension: III-D's economic cost",
        resolution=1e-4,
    ),
    ObjectiveSpec(
        ObjectiveName.ENERGY,
        "robot power",
        "W",
        "extension: idle + per core + radio per Mbps",
        resolution=1e-3,
    ),
    ObjectiveSpec(
        ObjectiveName.MIGRATIONS,
        "running instances moved",
        "instances",
        "extension: issue 10",
    ),
)

OBJECTIVE_SPECS: dict[str, ObjectiveSpec] = {s.name.value: s for s in _SPECS}
if set(OBJECTIVE_SPECS) != {o.value for o in ObjectiveName}:  # pragma: no cover
    raise RuntimeError("every ObjectiveName needs exactly one ObjectiveSpec")

# The objectives that measure missed deadlines, in the order the choice reads them.
MISS_OBJECTIVES: tuple[str, ...] = (
    ObjectiveName.MISS_RATE.value,
    ObjectiveName.MISSED_CYCLES.value,
)

# A RobotFleet's objectives when it names none, in priority order.
DEFAULT_OBJECTIVES: tuple[ObjectiveName, ...] = (
    ObjectiveName.MISS_RATE,
    ObjectiveName.MISSED_CYCLES,
    ObjectiveName.ONBOARD,
    ObjectiveName.RESERVE,
    ObjectiveName.BALANCE,
)
