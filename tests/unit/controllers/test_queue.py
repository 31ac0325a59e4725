"""The per-fleet queue: a burst of triggers makes one reconcile; runs never overlap.

Every test runs on a virtual clock (``virtualtime``): the delays the queue waits are the
delays asserted, exactly, however fast or loaded the machine is.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Awaitable, Callable

import pytest
from virtualtime import run_in_virtual_time

from fogfleet.controllers.outcome import Outcome
from fogfleet.runtime.queue import ReconcileQueue


def test_a_burst_of_triggers_makes_one_reconcile() -> None:
    calls: list[tuple[str, str]] = []

    async def runner(key: tuple[str, str]) -> Outcome:
        calls.append(key)
        return Outcome(ready=True)

    async def main() -> None:
        q = ReconcileQueue(runner, debounce=0.05)
        for _ in range(10):
            q.schedule(("ns", "fleet"))
            await asyncio.sleep(0.005)
        q.schedule(("ns", "other"))
        await asyncio.sleep(0.2)
        await q.close()

    run_in_virtual_time(main())
    assert sorted(calls) == [("ns", "fleet"), ("ns", "other")]


def test_reconciles_of_one_fleet_never_overlap_and_requeue_until_ready() -> None:
    active = 0
    peak = 0
    runs = 0

    async def runner(key: tuple[str, str]) -> Outcome:
        nonlocal active, peak, runs
        active += 1
        peak = max(peak, active)
        await asyncio.sleep(0.02)
        active -= 1
        runs += 1
        return Outcome(ready=runs >= 3, requeue_after=None if runs >= 3 else 0.01)

    async def main() -> None:
        q = ReconcileQueue(runner, debounce=0.01)
        await asyncio.gather(q.run_now(("ns", "f")), q.run_now(("ns", "f")))
        await asyncio.sleep(0.2)
        await q.close()

    run_in_virtual_time(main())
    assert peak == 1 and runs >= 3


def test_failing_background_runs_back_off_exponentially_and_a_success_resets() -> None:
    from fogfleet.errors import DependencyUnavailable
    from fogfleet.runtime.queue import backoff_delay

    assert [backoff_delay(10, k) for k in range(7)] == [10, 20, 40, 80, 160, 300, 300]
    stamps: list[float] = []

    async def runner(key: tuple[str, str]) -> Outcome:
        stamps.append(asyncio.get_running_loop().time())
        if len(stamps) <= 3:
            raise DependencyUnavailable("API server", "down", reason="ApiUnavailable")
        return Outcome(ready=True)

    async def main() -> ReconcileQueue:
        q = ReconcileQueue(runner, debounce=0.0, retry=0.02)
        q.schedule(("ns", "f"))
        await asyncio.sleep(0.4)
        await q.close()
        return q

    q = run_in_virtual_time(main())
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert len(stamps) == 4, stamps  # three failures, then the success: no more runs
    assert gaps == pytest.approx([0.02, 0.04, 0.08]), gaps
    assert q.failures(("ns", "f")) == 0  # a success resets the count


def _timing_runner(runs: list[float]) -> Callable[[tuple[str, str]], Awaitable[Outcome]]:
    """A runner that records the loop time of every reconcile."""

    async def runner(key: tuple[str, str]) -> Outcome:
        runs.append(asyncio.get_running_loop().time())
        return Outcome(ready=True)

    return runner


def test_a_stream_of_events_still_reconciles_every_max_wait() -> None:
    """Events every 20 ms for 0.6 s with a 0.1 s quiet period: plain debouncing would run
    once, after the stream; ``schedule_debounced`` runs at most ``max_wait`` (0.15 s) after a
    burst began, so the fleet is reconciled several times while the stream lasts."""
    runs: list[float] = []
    runner = _timing_runner(runs)

    async def main() -> float:
        q = ReconcileQueue(runner, debounce=0.1, max_wait=0.15)
        start = asyncio.get_running_loop().time()
        while asyncio.get_running_loop().time() - start < 0.6:
            q.schedule_debounced(("ns", "fleet"))
            await asyncio.sleep(0.02)
        end = asyncio.get_running_loop().time()
        await asyncio.sleep(0.3)
        await q.close()
        return end - start

    stream = run_in_virtual_time(main())
    during = [t for t in runs if t - runs[0] < stream]
    assert len(during) >= 3, runs
    gaps = [b - a for a, b in itertools.pairwise(runs)]
    # a burst begins at the first event after a run (events come every 20 ms) and runs at
    # most max_wait later; plain debouncing fails the count above
    assert max(gaps[: len(during) - 1], default=0.0) <= 0.15 + 0.02 + 1e-9, gaps


def test_a_quiet_burst_still_makes_one_reconcile_after_the_quiet_period() -> None:
    """A short burst (5 events within 40 ms) inside max_wait: one run, the quiet period after
    the last event (the debounce still coalesces)."""
    runs: list[float] = []
    runner = _timing_runner(runs)

    async def main() -> float:
        q = ReconcileQueue(runner, debounce=0.1, max_wait=1.0)
        for _ in range(5):
            q.schedule_debounced(("ns", "fleet"))
            last = asyncio.get_running_loop().time()
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.3)
        await q.close()
        return last

    last = run_in_virtual_time(main())
    assert len(runs) == 1 and runs[0] - last == pytest.approx(0.1), (runs, last)


def test_a_longer_max_wait_per_call_holds_a_stream_back() -> None:
    """The same stream as above with max_wait 1.0 given per call (a fleet with many modules
    still rolling out): no run while the 0.6 s stream lasts, one after it."""
    runs: list[float] = []
    runner = _timing_runner(runs)

    async def main() -> float:
        q = ReconcileQueue(runner, debounce=0.1, max_wait=0.15)
        start = asyncio.get_running_loop().time()
        while asyncio.get_running_loop().time() - start < 0.6:
            q.schedule_debounced(("ns", "fleet"), max_wait=1.0)
            await asyncio.sleep(0.02)
        end = asyncio.get_running_loop().time()
        await asyncio.sleep(0.3)
        await q.close()
        return end

    end = run_in_virtual_time(main())
    assert len(runs) == 1 and runs[0] >= end, (runs, end)


def test_forgetting_a_fleet_drops_its_lock_timer_and_failures() -> None:
    """A deleted fleet leaves nothing in the queue, even when it is forgotten while its lock
    is held (the reconcile that found it gone)."""
    gone = ("ns", "gone")
    held: list[set[tuple[str, str]]] = []

    async def runner(key: tuple[str, str]) -> Outcome | None:
        if key == gone:
            q.forget(key)  # what Runtime._forget does from inside the run
            held.append(q.held())
            return None
        raise RuntimeError("broken")  # a failure count and a retry timer

    async def main() -> set[tuple[str, str]]:
        q.schedule(("ns", "failing"), 0.0)
        await asyncio.sleep(0.05)
        assert ("ns", "failing") in q.held()
        q.forget(("ns", "failing"))
        await q.run_now(gone)
        left = q.held()
        await q.close()
        return left

    q = ReconcileQueue(runner, debounce=0.01, retry=60.0)
    assert run_in_virtual_time(main()) == set()
    assert held == [{gone}]  # while held, the lock stays (a waiter could be queued on it)


def test_a_closed_queue_runs_nothing_and_a_run_failing_while_it_closes_leaves_no_retry() -> None:
    """The operator stopping (or losing its Lease) closes the queue and then its threads: a run
    that fails meanwhile must not schedule a retry that would find the threads gone."""
    runs: list[float] = []
    closing: list[asyncio.Task[None]] = []

    async def runner(key: tuple[str, str]) -> Outcome:
        runs.append(asyncio.get_running_loop().time())
        closing.append(asyncio.create_task(q.close()))  # the operator stops during this run
        await asyncio.sleep(0)
        raise RuntimeError("the API server went away")

    async def main() -> tuple[bool, Outcome | None]:
        q.schedule(("ns", "f"), 0.0)  # a background run: its failure would be retried
        await asyncio.sleep(1.0)
        await asyncio.gather(*closing)
        q.schedule(("ns", "f"), 0.0)
        q.schedule_debounced(("ns", "g"))
        late = await q.run_now(("ns", "f"))
        await asyncio.sleep(600.0)  # longer than any retry
        return bool(q.pending()), late

    q = ReconcileQueue(runner, debounce=0.01, retry=0.01)
    pending, late = run_in_virtual_time(main())
    assert runs == [0.0] and not pending and late is None
