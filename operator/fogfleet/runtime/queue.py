"""Per-fleet serialisation and debouncing of reconciles (asyncio; the work itself runs in a thread).

- ``run_now(key)``: reconcile at once (kopf's create/update/resume/timer handlers await it, so
  kopf's retry and backoff apply); a pending debounced run for the key is dropped.
- ``schedule(key, delay)``: reconcile after ``delay`` seconds; a new call for the same key
  replaces the pending one.
- ``schedule_debounced(key, quiet)``: for watch events. A burst of them (modules, nodes,
  Deployments rolling) makes one reconcile, ``quiet`` seconds after the last, but never more
  than ``max_wait`` seconds after the burst's first: a steady stream (hundreds of Deployments
  whose status the controller-manager updates one after another) would otherwise hold the
  fleet's status back until the stream ends.

Errors of background runs are logged, counted and retried with an exponential backoff
(``backoff_delay``: the retry delay doubling per failure in a row, up to five minutes); a
success resets it. kopf's handler retries use the same schedule.

One record per fleet (``_Fleet``: its lock, timer, burst, failure count and the users of its
lock): two reconciles of the same fleet never overlap. ``forget(key)`` drops everything the
queue holds for a fleet that is gone (the record, once its lock's last holder or waiter
leaves), as kopf's queueing drops a resource's worker and its stream when the resource is
deleted.

Instrumented as controller-runtime's controllers and client-go's workqueue are (``metrics``):
every run's result and duration (``controller_runtime_reconcile_*{controller=name}``), the
fleets waiting for a run (``workqueue_depth{name}``: debounced, requeued or backing off), each
add and retry; forgetting a fleet drops its status series too.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field

from fogfleet.adapters.ports import MetricsPort, NullMetrics
from fogfleet.controllers.outcome import Outcome
from fogfleet.controllers.state import FleetKey
from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = ["DEFAULT_MAX_WAIT_SECONDS", "MAX_BACKOFF_SECONDS", "ReconcileQueue", "backoff_delay"]

log = logging.getLogger(__name__)
Runner = Callable[[FleetKey], Awaitable[Outcome | None]]
MAX_BACKOFF_SECONDS = 300.0
# a stream of watch events delays a fleet's reconcile by at most this much (schedule_debounced)
DEFAULT_MAX_WAIT_SECONDS = 2.0


def backoff_delay(base: float, attempt: int, cap: float = MAX_BACKOFF_SECONDS) -> float:
    """Seconds before retry number ``attempt`` (0: the first retry): ``base`` doubling."""
    return float(min(cap, base * 2 ** max(0, min(attempt, 30))))


@dataclass
class _Fleet:
    """What the queue holds for one fleet."""

    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    timer: asyncio.Task[None] | None = None  # the pending run
    burst: float | None = None  # when the pending debounced burst began (loop time)
    failures: int = 0  # failed background runs in a row
    users: int = 0  # holders and waiters of the lock
    forgotten: bool = False  # the fleet is gone: drop the record once its users left


class ReconcileQueue:
    def __init__(
        self,
        runner: Runner,
        *,
        debounce: float = 1.0,
        max_wait: float | None = None,
        retry: float = 10.0,
        on_error: Callable[[FleetKey, str], None] | None = None,
        metrics: MetricsPort | None = None,
        name: str = "robotfleet",
    ) -> None:
        self.runner = runner
        self.debounce = debounce
        self.max_wait = max(debounce, DEFAULT_MAX_WAIT_SECONDS) if max_wait is None else max_wait
        self.retry = retry
        self.on_error = on_error
        self._fleets: dict[FleetKey, _Fleet] = {}
        self._closed = False  # the operator is stopping (or lost its Lease): no new runs
        self.metrics: MetricsPort = metrics or NullMetrics()
        self.name = name
        self.metrics.init_controller(name)

    @contextlib.asynccontextmanager
    async def _locked(self, key: FleetKey) -> AsyncIterator[None]:
        """Hold the fleet's lock; the last user of a forgotten fleet's lock drops its record
        (unless the fleet was scheduled again meanwhile)."""
        fleet = self._fleets.setdefault(key, _Fleet())
        fleet.users += 1
        try:
            async with fleet.lock:
                yield
        finally:
            fleet.users -= 1
            if not fleet.users and fleet.forgotten:
                fleet.forgotten = False
                if fleet.timer is None and self._fleets.get(key) is fleet:
                    del self._fleets[key]

    def forget(self, key: FleetKey) -> None:
        """The fleet is gone: drop its timer, burst, failures and (once unused) its lock."""
        self.cancel(key)
        self.metrics.forget_fleet(*key)
        fleet = self._fleets.get(key)
        if fleet is None:
            return
        fleet.failures = 0
        if fleet.users:
            fleet.forgotten = True
        else:
            del self._fleets[key]

    def failures(self, key: FleetKey) -> int:
        """The fleet's failed background runs in a row."""
        fleet = self._fleets.get(key)
        return 0 if fleet is None else fleet.failures

    def held(self) -> set[FleetKey]:
        """The fleets the queue holds anything for (a lock, a timer or failures)."""
        return set(self._fleets)

    async def run_now(self, key: FleetKey) -> Outcome | None:
        """Reconcile at once; nothing once the queue is closed (the next leader reconciles
        every fleet when it starts)."""
        if self._closed:
            return None
        self.cancel(key)
        if key in self._fleets:
            self._fleets[key].forgotten = False  # a fleet created again under the same name
        async with self._locked(key):
            outcome = await self._reconcile(key)
        self._follow_up(key, outcome)
        return outcome

    async def _reconcile(self, key: FleetKey) -> Outcome | None:
        """One run of the runner, counted and timed as controller-runtime counts a reconcile."""
        t0 = time.perf_counter()
        try:
            outcome = await self.runner(key)
        except Exception:
            self.metrics.observe_reconcile(self.name, "error", time.perf_counter() - t0)
            raise
        requeue = outcome is not None and outcome.requeue_after is not None
        result = "requeue_after" if requeue else "success"
        self.metrics.observe_reconcile(self.name, result, time.perf_counter() - t0)
        return outcome

    def schedule(self, key: FleetKey, delay: float | None = None, *, retry: bool = False) -> None:
        if self._closed:
            return  # a run that ends (or fails) while the operator stops leaves no retry
        self.cancel(key)
        wait = self.debounce if delay is None else delay
        fleet = self._fleets.setdefault(key, _Fleet())
        fleet.timer = asyncio.get_running_loop().create_task(self._later(key, wait))
        self.metrics.count_queue_add(self.name, retry)
        self._depth()

    def _depth(self) -> None:
        self.metrics.set_queue_depth(self.name, len(self.pending()))

    def schedule_debounced(
        self, key: FleetKey, quiet: float | None = None, max_wait: float | None = None
    ) -> None:
        """Run ``quiet`` (default: the debounce) after the last of a burst of calls, at most
        ``max_wait`` (default: the queue's) after its first."""
        if self._closed:
            return
        now = asyncio.get_running_loop().time()
        fleet = self._fleets.get(key)
        burst = fleet.burst if fleet is not None and fleet.timer is not None else None
        first = now if burst is None else burst
        wait = self.debounce if quiet is None else quiet
        cap = self.max_wait if max_wait is None else max_wait
        self.schedule(key, max(0.0, min(wait, first + cap - now)))
        self._fleets[key].burst = first

    def cancel(self, key: FleetKey) -> None:
        fleet = self._fleets.get(key)
        if fleet is None:
            return
        fleet.burst = None
        task, fleet.timer = fleet.timer, None
        if task is not None and task is not asyncio.current_task():
            task.cancel()
        if task is not None:
            self._depth()

    def pending(self) -> set[FleetKey]:
        return {key for key, fleet in self._fleets.items() if fleet.timer is not None}

    async def _later(self, key: FleetKey, wait: float) -> None:
        await asyncio.sleep(wait)
        fleet = self._fleets.get(key)
        if fleet is not None and fleet.timer is asyncio.current_task():
            fleet.timer = None
            self._depth()
        outcome: Outcome | None = None
        try:
            async with self._locked(key):
                outcome = await self._reconcile(key)
        except InvalidSpec as exc:
            log.info("Left RobotFleet %s/%s as is: %s", *key, exc)
            return
        except DependencyUnavailable as exc:
            delay = self._failed(key, exc.reason)
            log.warning("Retrying RobotFleet %s/%s in %.0fs: %s", *key, delay, exc)
            return
        except Exception:
            delay = self._failed(key, "Unexpected")
            log.exception("Failed to reconcile RobotFleet %s/%s; retrying in %.0fs", *key, delay)
            return
        if key in self._fleets:
            self._fleets[key].failures = 0
        self._follow_up(key, outcome)

    def _failed(self, key: FleetKey, reason: str) -> float:
        fleet = self._fleets.setdefault(key, _Fleet())
        attempt, fleet.failures = fleet.failures, fleet.failures + 1
        delay = backoff_delay(self.retry, attempt)
        self._error(key, reason)
        self.schedule(key, delay, retry=True)
        return delay

    def _follow_up(self, key: FleetKey, outcome: Outcome | None) -> None:
        if outcome is not None and outcome.requeue_after is not None and key not in self.pending():
            self.schedule(key, outcome.requeue_after)

    def _error(self, key: FleetKey, reason: str) -> None:
        if self.on_error is not None:
            self.on_error(key, reason)

    async def close(self) -> None:
        """Cancel every pending run and take no new one (a retry scheduled after this would
        find the runtime's threads gone)."""
        self._closed = True
        tasks = [f.timer for f in self._fleets.values() if f.timer is not None]
        for fleet in self._fleets.values():
            fleet.timer = None
        self._depth()
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
