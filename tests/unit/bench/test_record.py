"""Benchmark records and the page generated from them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fogfleet.bench.autoscaling import METRICS
from fogfleet.bench.record import page, read_record, write_record
from fogfleet.commandline.cli import main


def test_a_record_keeps_the_result_with_its_date_machine_and_command(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    write_record(path, "scheduling", {"rows": [1, 2]}, ["fogfleet", "bench", "scheduling"])
    record = read_record(path)
    assert record["result"] == {"rows": [1, 2]}
    assert record["command"] == "fogfleet bench scheduling"
    assert "cores" in record["machine"] and record["date"].endswith("UTC")


def test_a_file_that_is_not_a_record_is_refused_naming_what_is_missing(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"suite": "x", "result": 1}))
    with pytest.raises(ValueError, match="command, date, machine"):
        read_record(path)


def test_the_page_shows_each_table_beside_its_date_machine_and_command() -> None:
    record = {"suite": "s", "date": "D", "machine": "M", "command": "C", "result": [3]}
    text = page("T", [record], {"s": lambda r: f"table {r[0]}"}, {"s": "what it measures"})
    assert "# T" in text and "## s" in text and "what it measures" in text
    assert "Measured D on M, with `C`." in text and "table 3" in text


def test_bench_page_renders_recorded_autoscaling_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """JSON turns the seeds into strings: the table is rendered from the record as read."""
    result = {"6": {"reactive-slo": {m: 0.5 for m in METRICS}}}
    path = tmp_path / "a.json"
    write_record(path, "autoscaling", result, ["fogfleet", "bench", "autoscaling"])
    out = tmp_path / "core.md"
    assert main(["bench", "page", "--records", str(path), "--out", str(out)]) == 0
    text = out.read_text()
    assert "reactive-slo" in text and "50.00%" in text and "fogfleet bench autoscaling" in text
