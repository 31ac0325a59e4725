"""A fleet's measured misses against its plan, as status and Events (issue 10)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.api.timestamps import timestamp
from fogfleet.domain.observed import ModuleDrift

from .state import DriftWatch

__all__ = ["DriftReport", "drift_events", "drift_report"]

Obj = dict[str, Any]


@dataclass(frozen=True)
class DriftReport:
    entries: list[Obj]  # status.measured
    condition: tuple[bool | None, str, str] | None  # Drift: status, reason, message


def drift_report(watch: DriftWatch | None, states: Mapping[str, ModuleDrift] | None) -> DriftReport:
    """``status.measured`` and the ``Drift`` condition (None: the fleet is not watched)."""
    settings = watch.settings if watch is not None else None
    if settings is None or not settings.enabled or states is None:
        return DriftReport([], None)
    entries: list[Obj] = []
    for module, d in sorted(states.items()):
        entry: Obj = {"module": module, "predictedMissRate": round(d.predicted, 4)}
        if d.measured is not None:
            entry["measuredMissRate"] = round(d.measured, 4)
            entry["cycles"] = round(d.cycles, 1)
        if d.since is not None:
            entry["driftingSince"] = timestamp(d.since)
        entries.append(entry)
    drifting = [(m, d) for m, d in sorted(states.items()) if d.since is not None]
    if drifting:
        text = "; ".join(
            f"{m} misses {(d.measured or 0) * 100:.1f}% of {d.cycles:.0f} cycles, "
            f"predicted {d.predicted * 100:.1f}%"
            for m, d in drifting
        )
        return DriftReport(entries, (True, "MissesAbovePlan", text))
    if not any(d.measured is not None for d in states.values()):
        return DriftReport(entries, (None, "NotMeasured", "No measured cycles since the plan yet"))
    return DriftReport(
        entries,
        (False, "AsPredicted", "Every measured module misses within the margin of the plan"),
    )


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
                    f"{e['module']} misses {e.get('measuredMissRate', 0) * 100:.1f}% of its "
                    f"cycles, the plan predicted {e['predictedMissRate'] * 100:.1f}%",
                )
            )
    return out
