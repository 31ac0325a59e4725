"""A module's sign of life in ``kubectl logs``: every ``FOGFLEET_LOG_INTERVAL_SECONDS``
(default 10 s) one line of the cycles it ran, the deadlines it missed and the messages it
received and published, in the last period and since it started.

The same counts are on /metrics (``fogfleet_cycle_time_seconds_count``,
``fogfleet_missed_cycles_total``, ``fogfleet_messages_*_total``); the log line is for a person
without Prometheus. A module that runs no cycle (inactive, a standby not in charge, waiting for
its first input) says so with 0 cycles, which is still a line.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TextIO

from fogfleet.contract.env import ENV_LOG_INTERVAL, LOG_INTERVAL_SECONDS

__all__ = ["Counts", "Tally", "heartbeat_line", "log_interval", "run_heartbeat"]


@dataclass(frozen=True)
class Counts:
    """What a module did, counted from its start."""

    cycles: int = 0
    missed: int = 0
    received: int = 0
    published: int = 0

    def minus(self, before: Counts) -> Counts:
        return Counts(
            self.cycles - before.cycles,
            self.missed - before.missed,
            self.received - before.received,
            self.published - before.published,
        )


class Tally:
    """The running counts, bumped by the module's threads (``WorkloadMetrics`` does)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._cycles = self._missed = self._received = self._published = 0

    def cycle(self, missed: bool) -> None:
        with self._lock:
            self._cycles += 1
            self._missed += missed

    def received(self) -> None:
        with self._lock:
            self._received += 1

    def published(self) -> None:
        with self._lock:
            self._published += 1

    def counts(self) -> Counts:
        with self._lock:
            return Counts(self._cycles, self._missed, self._received, self._published)


def log_interval(env: Mapping[str, str]) -> float:
    """Seconds between two lines from ``FOGFLEET_LOG_INTERVAL_SECONDS`` (0: no lines);
    ValueError naming the variable for anything but a number of seconds >= 0."""
    text = env.get(ENV_LOG_INTERVAL, "").strip()
    if not text:
        return LOG_INTERVAL_SECONDS
    try:
        seconds = float(text)
    except ValueError:
        seconds = -1.0
    if not seconds >= 0:  # also NaN
        raise ValueError(f"{ENV_LOG_INTERVAL}={text!r}: seconds between log lines, 0 or more")
    return seconds


def heartbeat_line(who: str, now: Counts, before: Counts, seconds: float) -> str:
    """``robot-1/localizer: 100 cycles (2 missed), 100 messages in, 100 out in the last 10 s;
    1000 cycles (5 missed) since the start``."""
    d = now.minus(before)
    return (
        f"fogfleet-workload: {who}: {d.cycles} cycles ({d.missed} missed), {d.received} "
        f"messages in, {d.published} out in the last {seconds:g} s; {now.cycles} cycles "
        f"({now.missed} missed) since the start"
    )


def run_heartbeat(
    tally: Tally, who: str, seconds: float, stop: threading.Event, out: TextIO | None = None
) -> None:
    """Write a line every ``seconds`` until ``stop`` is set (nothing when ``seconds`` is 0)."""
    if seconds <= 0:
        return
    stream = out if out is not None else sys.stdout
    before = tally.counts()
    while not stop.wait(seconds):
        now = tally.counts()
        print(heartbeat_line(who, now, before, seconds), file=stream, flush=True)
        before = now
