"""Resuming a stopped run of the schedule: what is left, and what is refused (pure)."""

from __future__ import annotations

from typing import Any

import pytest

from e2e.bench.real.protocol import Protocol
from e2e.bench.real.report import table
from e2e.bench.real.resume import ResumeRefused, part, runs_left
from e2e.bench.real.summary import summarise

PROTOCOL = Protocol()
SCHEDULE = PROTOCOL.schedule()


def _record(i: int) -> dict[str, Any]:
    r = SCHEDULE[i]
    return {"scheduler": r.arm, "seed": r.seed, "position": r.position, "block": r.block}


def _stopped(n: int, **changes: Any) -> dict[str, Any]:
    doc = {
        "complete": False,
        "protocol": PROTOCOL.as_json(),
        "runs": [_record(i) for i in range(n)],
        "date": "2026-11-29",
        "machine": "Intel(R) Xeon(R) Processor, 2 cores",
        "command": "python -m e2e.bench.real",
        "totalSeconds": 3500,
    }
    return doc | changes


def test_the_runs_left_are_the_schedules_tail_in_their_places() -> None:
    left = runs_left(_stopped(13), PROTOCOL.as_json(), SCHEDULE)
    assert [r.position for r in left] == list(range(13, 25))
    assert left == SCHEDULE[13:]


@pytest.mark.parametrize(
    ("doc", "reason"),
    [
        (_stopped(13, complete=True), "complete"),
        (_stopped(13, protocol=Protocol(window_s=30).as_json()), "protocol differs"),
        (_stopped(25), "all 25"),
        (_stopped(3, runs=[_record(0), _record(2), _record(1)]), "run 2"),
    ],
)
def test_a_run_that_cannot_be_resumed_is_refused_with_the_reason(
    doc: dict[str, Any], reason: str
) -> None:
    with pytest.raises(ResumeRefused, match=reason):
        runs_left(doc, PROTOCOL.as_json(), SCHEDULE)


def test_a_resumed_run_names_its_parts() -> None:
    stopped = _stopped(13)
    whole = {
        **stopped,
        "complete": True,
        "runs": stopped["runs"],
        "summary": summarise([]),
        "parts": [part(stopped, 1, 13), part(stopped | {"totalSeconds": 3000}, 14, 25)],
    }
    text = table(whole)
    assert "Ran in 2 parts: runs 1-13 on 2026-11-29, Intel(R) Xeon(R) Processor" in text
    assert "runs 14-25" in text and "3000 s" in text
    assert "different machines" not in text
    other = part(stopped | {"machine": "AMD EPYC, 2 cores"}, 14, 25)
    text = table({**whole, "parts": [whole["parts"][0], other]})
    assert "runs 14-25 on 2026-11-29, AMD EPYC, 2 cores" in text
    assert "The parts ran on 2 different machines" in text
