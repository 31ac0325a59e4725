"""The fault record and the docs table it renders (pure: no bed)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from e2e.faults import report
from e2e.faults.record import ENV_RECORD, FaultResult, read_results, record, record_measured


def test_a_recorded_result_is_printed_and_appended(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "faults.json"
    monkeypatch.setenv(ENV_RECORD, str(path))
    record(FaultResult("kubelet restart", 0, 2, 11.5, "nothing", test="t::a"))
    record(FaultResult("kubelet restart", 1, 3, 12.0, "nothing", test="t::a"))
    assert capsys.readouterr().out.startswith("FAULT-RESULT {")
    (only,) = read_results(path)  # the last result of a fault wins
    assert only["cycles_missed"] == 3 and only["machine"]


def test_a_line_that_is_not_a_result_is_named(tmp_path: Path) -> None:
    path = tmp_path / "faults.json"
    path.write_text(json.dumps({"fault": "x"}) + "\n")
    with pytest.raises(ValueError, match=r"faults.json:1: a fault result lacks cycles_missed"):
        read_results(path)


def test_the_page_keeps_its_prose_and_gets_the_table(tmp_path: Path) -> None:
    results = tmp_path / "faults.json"
    results.write_text(
        json.dumps(
            {
                "fault": "link cut | 90 s",
                "messages_lost": 0,
                "cycles_missed": 0,
                "recovery_seconds": 3.25,
                "fogfleet_did": "kept the standby",
                "machine": "m",
            }
        )
        + "\n"
    )
    docs = tmp_path / "survives.md"
    docs.write_text(f"# Page\n\nprose\n\n{report.BEGIN}\nold\n{report.END}\n\nafter\n")
    assert report.main(["--json", str(results), "--docs", str(docs)]) == 0
    text = docs.read_text()
    assert "prose" in text and "after" in text and "old" not in text
    assert "| link cut \\| 90 s | 0 | 0 | 3.2 | kept the standby |" in text
    assert "with `make test-faults`" in text


def test_a_page_without_the_markers_is_refused(tmp_path: Path) -> None:
    results = tmp_path / "faults.json"
    results.write_text(
        json.dumps(
            {
                "fault": "f",
                "messages_lost": 0,
                "cycles_missed": 0,
                "recovery_seconds": 1,
                "fogfleet_did": "x",
            }
        )
        + "\n"
    )
    docs = tmp_path / "survives.md"
    docs.write_text("# Page\n")
    assert report.main(["--json", str(results), "--docs", str(docs)]) == 2


def test_measured_figures_keep_their_extras_as_details(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "faults.json"
    monkeypatch.setenv(ENV_RECORD, str(path))
    got = record_measured(
        {
            "fault": "f",
            "messagesLost": 2,
            "cyclesMissed": 0,
            "recoverySeconds": 1.5,
            "fogfleetDid": "x",
            "nodeReadySeconds": 9,
        }
    )
    assert got.messages_lost == 2 and got.details == {"nodeReadySeconds": 9}
    with pytest.raises(ValueError, match="lacks fogfleetDid"):
        record_measured(
            {"fault": "f", "messagesLost": 2, "cyclesMissed": 0, "recoverySeconds": 1.5}
        )
