"""run_all: every call made, a few at a time; the first failure stops what has not started."""

from __future__ import annotations

import threading
import time

import pytest

from fogfleet.controllers.parallel import run_all
from fogfleet.errors import DependencyUnavailable


def test_every_call_runs_and_at_most_workers_at_once():
    lock = threading.Lock()
    running, peak, done = [0], [0], []

    def call(k: int) -> None:
        with lock:
            running[0] += 1
            peak[0] = max(peak[0], running[0])
        time.sleep(0.02)
        with lock:
            running[0] -= 1
            done.append(k)

    run_all([lambda k=k: call(k) for k in range(20)], workers=4)
    assert sorted(done) == list(range(20))
    assert 2 <= peak[0] <= 4


def test_the_first_failure_is_raised_and_calls_not_started_are_dropped():
    started: list[int] = []

    def call(k: int) -> None:
        started.append(k)
        if k == 0:
            raise DependencyUnavailable("Cannot apply: connection refused")
        time.sleep(0.05)

    with pytest.raises(DependencyUnavailable, match="connection refused"):
        run_all([lambda k=k: call(k) for k in range(40)], workers=2)
    assert 0 in started and len(started) < 10


def test_one_worker_runs_in_order_and_stops_at_the_first_failure():
    seen: list[int] = []

    def call(k: int) -> None:
        seen.append(k)
        if k == 2:
            raise ValueError("bad")

    with pytest.raises(ValueError):
        run_all([lambda k=k: call(k) for k in range(5)], workers=1)
    assert seen == [0, 1, 2]
