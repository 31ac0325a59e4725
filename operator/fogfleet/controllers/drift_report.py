"""A fleet's measured misses against its plan, as status and Events (issue 10).

The rule in one sentence, as the ``Drift`` condition says it: a module drifts when it misses
more than predicted by more than its real-time class affords (``domain.observed``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.api.timestamps import timestamp
from fogfleet.domain.miss_rates import format_miss_rate, pooled_miss_rate
from fogfleet.domain.observed import ModuleDrift

from .state import DriftWatch

__all__ = ["AS_PREDICTED", "DriftReport", "drift_events", "drift_report"]

AS_PREDICTED = (
    "Every measured module misses within what its real-time class affords above the plan "
    "(spec.drift.marginPercent points for soft real-time, a hundredth of that for hard "
    "real-time or safety-critical, twice that for the rest)"
)

Obj = dict[str, Any]


@dataclass(frozen=True)
class DriftReport:
    entries: list[Obj]  # status.measured
    condition: tuple[bool | None, str, str] | None  # Drift: status, reason, message
    # status.measuredMissRate: the measured modules' missed over their cycles (None: none)
    measured_miss_rate: float | None = None


def drift_report(watch: DriftWatch | None, states: Mapping[str, ModuleDrift] | None) -> DriftReport:
    """``status.measured`` and the ``Drift`` condition (None: the fleet is not watched)."""
    settings = watch.settings if watch is not None else None
    if settings is None or not settings.enabled or states is None:
        return DriftReport([], None)
    entries: list[Obj] = []
    for module, d in sorted(states.items()):
        entry: Obj = {
            "module": module,
            "predictedMissRate": round(d.predicted, 6),
            "driftMargin": round(d.budget.allowance, 6),
        }
        if d.measured is not None:
            entry["measuredMissRate"] = round(d.measured, 6)
            entry["cycles"] = round(d.cycles, 1)
        if d.since is not None:
            entry["driftingSince"] = timestamp(d.since)
        entries.append(entry)
    pooled = pooled_miss_rate((d.measured, d.cycles) for d in states.values())
    drifting = [(m, d) for m, d in sorted(states.items()) if d.since is not None]
    if drifting:
        text = "; ".join(
            f"{m} misses {format_miss_rate(d.measured or 0)} of {d.cycles:.0f} cycles, "
            f"predicted {format_miss_rate(d.predicted)}: more than the "
            f"{d.budget.describe()} it affords"
            for m, d in drifting
        )
        return DriftReport(entries, (True, "MissesAbovePlan", text), pooled)
    if not any(d.measured is not None for d in states.values()):
        return DriftReport(entries, (None, "NotMeasured", "No measured cycles since the plan yet"))
    return DriftReport(entries, (False, "AsPredicted", AS_PREDICTED), pooled)


def drift_events(old: list[Obj], new: list[Obj]) -> list[tuple[str, str, str]]:
    """A Warning for each module that started drifting since the last status."""
    before = {str(e.get("module")): e for e in old or []}
    out = []
    for e in new:
        if e.get("driftingSince") and not before.get(e["module"], {}).get("driftingSince"):
            out.append(
                (
                    "Warning",
                    "Drift",
                    f"{e['module']} misses {format_miss_rate(e.get('measuredMissRate', 0))} of "
                    f"its cycles, the plan predicted {format_miss_rate(e['predictedMissRate'])}"
                    + _margin_text(e),
                )
            )
    return out


def _margin_text(entry: Obj) -> str:
    """", more than 0.05 points above it" (a status written before the margin was kept says
    nothing)."""
    margin = entry.get("driftMargin")
    return "" if margin is None else f", more than {margin * 100:.3g} points above it"
