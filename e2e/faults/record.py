"""What one injected fault cost, as the fault tests measure it, and the file they append to.

Each ``faults`` test calls :func:`record` once per fault with the figures it asserted on:
messages lost, cycles missed, seconds until everything ran as planned again, and what fogfleet
did (and did before the fix that made it recover). The line is always printed; when
``FOGFLEET_FAULTS_RECORD`` names a file (``make test-faults`` sets it), the result is also
appended there, and ``python -m e2e.faults.report`` renders the table of docs/survives.md
from that file, with date, machine and command.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from fogfleet.bench.record import machine

__all__ = ["ENV_RECORD", "FaultResult", "read_results", "record", "record_measured"]

ENV_RECORD = "FOGFLEET_FAULTS_RECORD"


@dataclass(frozen=True)
class FaultResult:
    """One fault and its cost. ``messages_lost`` and ``cycles_missed`` are counts summed over
    the fleet's workloads (from their own counters); ``recovery_seconds`` runs from the fault
    to the fleet being as planned again (Ready, every pod on its planned node, inputs
    flowing)."""

    fault: str
    messages_lost: float | None  # None: the test sends no counted messages
    cycles_missed: float | None  # None: not a fault the fleet's cycles can feel
    recovery_seconds: float
    fogfleet_did: str
    before_fix: str = "the same (no fix needed)"
    test: str = ""
    details: dict[str, Any] = field(default_factory=dict)  # the test's own figures

    def line(self) -> str:
        return "FAULT-RESULT " + json.dumps(asdict(self), sort_keys=True)


def record(result: FaultResult) -> FaultResult:
    """Print ``result`` (pytest shows it with ``-s`` and in a failure's output) and append it
    to the record file when one is named."""
    test = result.test or os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0]
    result = FaultResult(**{**asdict(result), "test": test})
    print(result.line(), flush=True)
    path = os.environ.get(ENV_RECORD)
    if path:
        entry: dict[str, Any] = {**asdict(result), "machine": machine()}
        with Path(path).open("a") as out:
            out.write(json.dumps(entry, sort_keys=True) + "\n")
    return result


_FIELDS = {"fault": "fault", "messagesLost": "messages_lost", "cyclesMissed": "cycles_missed",
           "recoverySeconds": "recovery_seconds", "fogfleetDid": "fogfleet_did",
           "beforeFix": "before_fix"}  # fmt: skip


def record_measured(measured: Mapping[str, Any]) -> FaultResult:
    """:func:`record` from a test's figures as JSON names them (``messagesLost`` ...): the
    table's fields by their names, every other figure kept in ``details``."""
    missing = {"fault", "messagesLost", "cyclesMissed", "recoverySeconds", "fogfleetDid"}
    missing -= set(measured)
    if missing:
        raise ValueError(f"a fault result lacks {', '.join(sorted(missing))}")
    fields = {_FIELDS[k]: v for k, v in measured.items() if k in _FIELDS}
    details = {k: v for k, v in measured.items() if k not in _FIELDS}
    return record(FaultResult(**fields, details=details))


def read_results(path: Path) -> list[dict[str, Any]]:
    """The results in ``path`` (JSON lines), the last one of each fault kept."""
    by_fault: dict[str, dict[str, Any]] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as err:
            raise ValueError(f"{path}:{n}: not a fault result ({err.msg})") from err
        missing = {"fault", "messages_lost", "cycles_missed", "recovery_seconds",
                   "fogfleet_did"} - set(entry)  # fmt: skip
        if missing:
            raise ValueError(f"{path}:{n}: a fault result lacks {', '.join(sorted(missing))}")
        by_fault[entry["fault"]] = entry
    return list(by_fault.values())
