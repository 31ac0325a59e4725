"""The one way status writers set their conditions (``controllers.status.set_conditions``,
after apimachinery's ``meta.SetStatusCondition``) and find one (``find_condition``)."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import ValidationError

from fogfleet.controllers import status as status_module
from fogfleet.controllers.status import (
    condition,
    find_condition,
    merge_conditions,
    set_conditions,
)

Obj = dict[str, Any]
THEN, NOW = "2026-11-28T10:00:00Z", "2026-11-29T12:00:00Z"


@pytest.fixture(autouse=True)
def _clock(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(status_module, "now", lambda: NOW)


def _old(type_: str, ok: bool, reason: str = "Was") -> Obj:
    return {**condition(type_, ok, reason, "before", 1), "lastTransitionTime": THEN}


def test_a_condition_keeps_its_transition_time_until_its_status_changes() -> None:
    old = [_old("Ready", True), _old("Scheduled", True)]
    new = [
        condition("Ready", True, "AllModulesRunning", "a new message", 2),
        condition("Scheduled", False, "Infeasible", "no placement fits", 2),
    ]
    got = {c["type"]: c for c in set_conditions(old, new)}
    assert got["Ready"]["lastTransitionTime"] == THEN  # same status: a new reason is no transition
    assert got["Ready"]["reason"] == "AllModulesRunning" and got["Ready"]["observedGeneration"] == 2
    assert got["Scheduled"]["lastTransitionTime"] == NOW  # True -> False


def test_other_writers_conditions_stay_after_ours_unless_dropped() -> None:
    """A module's scaling pass sets Scaling and MetricsUnavailable and must keep what other
    writers set; a fleet's full status replaces the whole list."""
    old = [_old("Profiled", True), _old("Scaling", True), _old("Drift", False)]
    new = [condition("Scaling", True, "Stable", "3 replicas", 1)]
    assert [c["type"] for c in set_conditions(old, new)] == ["Scaling", "Profiled", "Drift"]
    assert [c["type"] for c in merge_conditions(old, new)] == ["Scaling"]
    kept = set_conditions(old, new, keep=lambda type_: type_ == "Drift")
    assert [c["type"] for c in kept] == ["Scaling", "Drift"]
    assert kept[1] == old[2]  # kept as it was, its stamp too


def test_a_condition_first_set_gets_the_current_time_and_none_is_found_before() -> None:
    assert find_condition(None, "Ready") is None
    assert find_condition([_old("Scheduled", True)], "Ready") is None
    got = set_conditions([], [condition("Ready", None, "Waiting", "", None)])
    assert got[0]["lastTransitionTime"] == NOW and got[0]["status"] == "Unknown"
    assert find_condition(got, "Ready") == got[0]


def test_a_reason_that_is_not_one_camelcase_word_fails_in_the_writer() -> None:
    with pytest.raises(ValidationError, match="reason"):
        condition("Ready", False, "no placement fits", "", 1)
