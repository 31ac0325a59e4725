"""Resuming a stopped run of the protocol (``--resume bench-real.json``).

A run of the schedule that was stopped before its end (``complete`` false) is finished by
running the scheduled runs it never started, in their places, and keeping the runs it has as
they were recorded. Nothing else may differ: the protocol (arms, runs, blocks, warm-up,
windows, k8s-requests' requests) must be the one the stopped run recorded, and its runs must
be the schedule's first ones, in order; otherwise it is refused with the reason. The document
says which runs ran in which part, when and on which machine (``parts``), and the report prints
it: blocks keep every arm balanced over the parts, but a part on another machine is a
difference every reader must see.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from e2e.bench.real.protocol import ScheduledRun

__all__ = ["ResumeRefused", "part", "runs_left"]


class ResumeRefused(ValueError):
    """The stopped document cannot be resumed with this protocol (the reason is the text)."""


def runs_left(
    stopped: Mapping[str, Any], protocol_json: Mapping[str, Any], schedule: Sequence[ScheduledRun]
) -> list[ScheduledRun]:
    """The scheduled runs the stopped document never started (the schedule's tail)."""
    if stopped.get("complete", True):
        raise ResumeRefused("it is complete (its 'complete' is not false): nothing to resume")
    if dict(stopped.get("protocol") or {}) != dict(protocol_json):
        raise ResumeRefused(
            "its protocol differs from this run's (arms, runs, windows or requests); "
            "a resumed run must keep the protocol it started with"
        )
    runs = list(stopped.get("runs") or [])
    for i, (done, planned) in enumerate(zip(runs, schedule, strict=False)):
        got = (done.get("position"), done.get("scheduler"), done.get("seed"))
        if got != (planned.position, planned.arm, planned.seed):
            raise ResumeRefused(
                f"its run {i + 1} is {got}, where the schedule has "
                f"{(planned.position, planned.arm, planned.seed)}"
            )
    if len(runs) >= len(schedule):
        raise ResumeRefused(f"it holds all {len(schedule)} scheduled runs already")
    return list(schedule[len(runs) :])


def part(doc: Mapping[str, Any], first: int, last: int) -> dict[str, Any]:
    """One part of a resumed run as the document records it: which runs, when, on which
    machine, how long (a resumed run may run on another machine: the page says so)."""
    return {
        "runs": [first, last],
        "date": doc.get("date"),
        "machine": doc.get("machine"),
        "command": doc.get("command"),
        "totalSeconds": doc.get("totalSeconds"),
    }
