"""snapshot.objects: the one reader of a SoftwareModule's recorded status (issue 45)."""

from __future__ import annotations

from typing import Any

from fogfleet.snapshot.objects import profiled, profiling_record, recorded_corrections


def _module(name: str, status: dict[str, Any] | None) -> dict[str, Any]:
    body: dict[str, Any] = {"metadata": {"name": name}}
    if status is not None:
        body["status"] = status
    return body


def test_what_profiling_recorded_is_a_planning_input_per_module() -> None:
    rows = [{"hardwareType": "pi4", "cpu": "1", "meanMillis": 40.0, "stdMillis": 2.0}]
    modules = [
        _module("slam", {"profiling": {"rows": rows}}),
        _module("camera", None),
        _module("lidar", {"profiling": None}),
    ]
    assert profiling_record(modules[0]) == {"rows": rows}
    assert profiling_record(modules[1]) is None and profiling_record(modules[2]) is None
    assert profiled(modules) == (("slam", repr(rows)),)
    # a new row is a new input: the reconcile's fingerprint changes
    more = [*rows, {"hardwareType": "i9", "cpu": "1", "meanMillis": 10.0, "stdMillis": 1.0}]
    assert profiled([_module("slam", {"profiling": {"rows": more}})]) != profiled(modules)


def test_recorded_corrections_are_keyed_by_hardware_type_and_skip_what_is_not_an_entry() -> None:
    status = {"profileCorrection": [{"hardwareType": "pi4", "factor": 1.3}, "garbage"]}
    assert recorded_corrections(_module("slam", status)) == {
        "pi4": {"hardwareType": "pi4", "factor": 1.3}
    }
    assert recorded_corrections(_module("slam", None)) == {}
