"""run_all: every call made, a few at a time; the first failure stops what has not started."""

from __future__ import annotations

import threading

import pytest

from fogfleet.controllers import parallel
from fogfleet.controllers.parallel import run_all
from fogfleet.errors import DependencyUnavailable


def test_every_call_runs_and_at_most_workers_at_once():
    """Each call holds its worker until a second call runs beside it (or 10 s pass: only a
    guard against a hang), so the overlap is proven without racing a sleep."""
    cond = threading.Condition()
    running, peak, done = [0], [0], []

    def call(k: int) -> None:
        with cond:
            running[0] += 1
            peak[0] = max(peak[0], running[0])
            cond.notify_all()
            cond.wait_for(lambda: peak[0] >= 2 or k == 19, timeout=10)
            running[0] -= 1
            done.append(k)

    run_all([lambda k=k: call(k) for k in range(20)], workers=4)
    assert sorted(done) == list(range(20))
    assert 2 <= peak[0] <= 4


def test_the_first_failure_is_raised_and_calls_not_started_are_dropped(monkeypatch):
    """The calls after the failing one block until run_all has seen the failure (its
    ``wait`` returned); released, the worker takes the next queued calls at once, before the
    caller's thread may run again to cancel them (a busy machine): each must find the failure
    and not start. At most the one other call that was running when it failed ran."""
    started: list[int] = []
    seen_failure = threading.Event()
    real_wait = parallel.wait

    def wait_then_release(*args, **kwargs):
        result = real_wait(*args, **kwargs)
        seen_failure.set()
        return result

    monkeypatch.setattr(parallel, "wait", wait_then_release)

    def call(k: int) -> None:
        started.append(k)
        if k == 0:
            raise DependencyUnavailable("Cannot apply: connection refused")
        assert seen_failure.wait(timeout=10)

    with pytest.raises(DependencyUnavailable, match="connection refused"):
        run_all([lambda k=k: call(k) for k in range(40)], workers=2)
    assert 0 in started and len(started) <= 2, started


def test_one_worker_runs_in_order_and_stops_at_the_first_failure():
    seen: list[int] = []

    def call(k: int) -> None:
        seen.append(k)
        if k == 2:
            raise ValueError("bad")

    with pytest.raises(ValueError):
        run_all([lambda k=k: call(k) for k in range(5)], workers=1)
    assert seen == [0, 1, 2]
