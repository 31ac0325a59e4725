"""A module's log line every FOGFLEET_LOG_INTERVAL_SECONDS (issue 36: a sign of life)."""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Callable

import pytest

from fogfleet.workload.heartbeat import Counts, Tally, heartbeat_line, log_interval, run_heartbeat
from fogfleet.workload.metrics import WorkloadMetrics


def test_the_period_is_10_s_unless_the_environment_says_otherwise() -> None:
    assert log_interval({}) == 10.0
    assert log_interval({"FOGFLEET_LOG_INTERVAL_SECONDS": "2.5"}) == 2.5
    assert log_interval({"FOGFLEET_LOG_INTERVAL_SECONDS": "0"}) == 0.0  # no lines


@pytest.mark.parametrize("bad", ["-1", "soon", "nan"])
def test_a_bad_period_is_refused_naming_the_variable(bad: str) -> None:
    with pytest.raises(ValueError, match="FOGFLEET_LOG_INTERVAL_SECONDS"):
        log_interval({"FOGFLEET_LOG_INTERVAL_SECONDS": bad})


def test_the_line_says_cycles_misses_and_messages_of_the_period_and_in_all() -> None:
    line = heartbeat_line(
        "robot-1/localizer", Counts(1000, 5, 990, 1000), Counts(900, 3, 890, 899), 10
    )
    assert line == (
        "fogfleet-workload: robot-1/localizer: 100 cycles (2 missed), 100 messages in, 101 "
        "out in the last 10 s; 1000 cycles (5 missed) since the start"
    )


def test_the_metrics_count_what_the_line_reports() -> None:
    metrics = WorkloadMetrics("localizer", "robot-1", "robot")
    for seconds in (0.01, 0.2, 0.05):
        metrics.cycle_done(seconds, 0.1)
    metrics.received("scan")
    metrics.published("pose")
    metrics.published("pose")
    assert metrics.tally.counts() == Counts(cycles=3, missed=1, received=1, published=2)


def _lines_once(out: io.StringIO, ready: Callable[[list[str]], bool]) -> list[str]:
    """The lines written so far, once ``ready`` holds of them (10 s: only a guard against a
    hang; waiting on what was written, not on a sleep, holds on a loaded machine)."""
    deadline = time.monotonic() + 10
    while not ready(lines := out.getvalue().splitlines()):
        assert time.monotonic() < deadline, f"timed out; lines so far: {lines}"
        time.sleep(0.01)
    return lines


def _in_all(line: str) -> int:
    return int(line.split("; ")[1].split()[0])


def test_a_line_is_written_every_period_until_stopped() -> None:
    tally, stop, out = Tally(), threading.Event(), io.StringIO()
    worker = threading.Thread(
        target=run_heartbeat, args=(tally, "shared/detector", 0.05, stop, out)
    )
    worker.start()
    for _ in range(5):
        tally.cycle(missed=False)
    _lines_once(out, lambda lines: len(lines) >= 1)
    for _ in range(5):
        tally.cycle(missed=False)
    _lines_once(out, lambda lines: bool(lines) and _in_all(lines[-1]) == 10)
    stop.set()
    worker.join(timeout=10)
    assert not worker.is_alive()
    lines = out.getvalue().splitlines()
    assert len(lines) >= 2, lines
    assert all(line.startswith("fogfleet-workload: shared/detector: ") for line in lines)
    # each period counts its own cycles: together, every cycle once
    in_periods = sum(int(line.split(": ")[2].split()[0]) for line in lines)
    assert in_periods == _in_all(lines[-1]) == 10, lines


def test_a_period_of_0_writes_nothing() -> None:
    out = io.StringIO()
    run_heartbeat(Tally(), "robot-1/x", 0.0, threading.Event(), out)
    assert out.getvalue() == ""


def test_the_module_command_takes_the_period_as_an_argument() -> None:
    """A template cannot set FOGFLEET_* variables (they are fogfleet's): its args can."""
    from fogfleet.workload.__main__ import _log_seconds

    assert _log_seconds("30") == 30.0 and _log_seconds("0") == 0.0
    with pytest.raises(Exception, match="seconds, 0 or more"):
        _log_seconds("-5")
