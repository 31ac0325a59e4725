"""A fleet's measured misses against its plan, as status and Events (issue 10).

The rule in one sentence, as the ``Drift`` condition says it: a module drifts when it misses
more than predicted by more than its real-time class affords (``domain.observed``). A drifting
module that cannot leave its robot (``domain.onboard``) cannot be re-planned away from its
misses: the condition says whether its robot can give it the CPU its measured execution time
needs, or by how much CPU the robot is short for it (``status.measured[].cpuNeeded`` and
``cpuShort``, and a ``RobotShortOfCpu`` Event when the shortfall appears).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.base import format_cores
from fogfleet.controllers.state import DriftWatch
from fogfleet.domain.miss_rates import format_miss_rate, pooled_miss_rate
from fogfleet.domain.observed import ModuleDrift
from fogfleet.domain.onboard import OnboardNeed

__all__ = ["AS_PREDICTED", "DriftReport", "drift_events", "drift_report", "onboard_note"]

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
    # drifting module that cannot leave its robot -> what the fleet says of its robots
    notes: Mapping[str, str] = field(default_factory=dict)


def drift_report(
    watch: DriftWatch | None,
    states: Mapping[str, ModuleDrift] | None,
    onboard: Mapping[str, Sequence[OnboardNeed]] | None = None,
) -> DriftReport:
    """``status.measured`` and the ``Drift`` condition (None: the fleet is not watched);
    ``onboard``: what each drifting module that cannot leave its robot needs there."""
    settings = watch.settings if watch is not None else None
    if settings is None or not settings.enabled or states is None:
        return DriftReport([], None)
    pinned = {m: needs for m, needs in (onboard or {}).items() if needs and m in states}
    notes = {m: onboard_note(m, states[m], needs) for m, needs in pinned.items()}
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
        if d.since is not None and module in pinned:
            worst = pinned[module][0]
            entry["cpuNeeded"] = format_cores(worst.needed)
            if worst.short > 0:
                entry["cpuShort"] = format_cores(worst.short)
        entries.append(entry)
    pooled = pooled_miss_rate((d.measured, d.cycles) for d in states.values())
    drifting = [(m, d) for m, d in sorted(states.items()) if d.since is not None]
    if drifting:
        text = "; ".join(
            f"{m} misses {format_miss_rate(d.measured or 0)} of {d.cycles:.0f} cycles, "
            f"predicted {format_miss_rate(d.predicted)}: more than the "
            f"{d.budget.describe()} it affords" + (f"; {notes[m]}" if m in notes else "")
            for m, d in drifting
        )
        return DriftReport(entries, (True, "MissesAbovePlan", text), pooled, notes)
    if not any(d.measured is not None for d in states.values()):
        return DriftReport(entries, (None, "NotMeasured", "No measured cycles since the plan yet"))
    return DriftReport(entries, (False, "AsPredicted", AS_PREDICTED), pooled)


def onboard_note(module: str, drift: ModuleDrift, needs: Sequence[OnboardNeed]) -> str:
    """What a drifting module that cannot leave its robot needs there, as the Drift
    condition and the RobotShortOfCpu Event say it (``needs``: shortest robot first)."""
    worst = needs[0]
    pin = drift.budget.realtime
    why = pin if pin in ("hard real-time", "safety-critical") else "its requirements pin it"
    measured = (
        f"its measured execution time ({worst.exec_time * 1e3:.1f} ms at the 95th percentile "
        f"under a {format_cores(worst.cpu)} CPU limit, cycle {worst.cycle * 1e3:.1f} ms) needs "
        f"{format_cores(worst.needed)} CPU"
    )
    if worst.short <= 0:
        return (
            f"{module} cannot leave its robot ({why}): {measured}, which robot {worst.robot} "
            f"can guarantee it ({format_cores(worst.available)}), so its misses come from more "
            "than its work's CPU (wake-ups, middleware, CPU throttling)"
        )
    short = sum(1 for n in needs if n.short > 0)
    text = (
        f"{module} cannot leave its robot ({why}) and robot {worst.robot} lacks "
        f"{format_cores(worst.short)} CPU for it: {measured}, the robot can guarantee it "
        f"{format_cores(worst.available)} (its request and the robot's unreserved CPU)"
    )
    if len(needs) > 1:
        some = f"all {short}" if short == len(needs) else f"{short} of the {len(needs)}"
        text += f"; {some} of its robots are short"
    return text


def drift_events(
    old: list[Obj], new: list[Obj], notes: Mapping[str, str] | None = None
) -> list[tuple[str, str, str]]:
    """A Warning for each module that started drifting since the last status, and a
    RobotShortOfCpu Warning for each that cannot leave its robot and whose robot became short
    of CPU for it (``notes``: what the Drift condition says of those modules)."""
    before = {str(e.get("module")): e for e in old or []}
    out = []
    for e in new:
        if e.get("cpuShort") and not before.get(e["module"], {}).get("cpuShort"):
            note = (notes or {}).get(e["module"]) or (
                f"{e['module']} cannot leave its robot, which lacks {e['cpuShort']} CPU for it "
                f"(it needs {e.get('cpuNeeded')})"
            )
            out.append(("Warning", "RobotShortOfCpu", note))
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
    """ ", more than 0.05 points above it" (a status written before the margin was kept says
    nothing)."""
    margin = entry.get("driftMargin")
    return "" if margin is None else f", more than {margin * 100:.3g} points above it"
