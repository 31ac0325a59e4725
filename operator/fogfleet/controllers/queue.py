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

One lock per fleet: two reconciles of the same fleet never overlap. ``forget(key)`` drops
everything the queue holds for a fleet that is gone (its timer, burst, failure count and lock;
the lock once its last holder or waiter leaves), as kopf's queueing drops a resource's worker
and its stream when the resource is deleted.

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

from fogfleet.adapters.ports import MetricsPort, NullMetrics
from fogfleet.errors import DependencyUnavailable, InvalidSpec

from .outcome import Outcome
from .state import FleetKey

__all__ = ["DEFAULT_MAX_WAIT_SECONDS", "MAX_BACKOFF_SECONDS", "ReconcileQueue", "backoff_delay"]

log = logging.getLogger(__name__)
Runner = Callable[[FleetKey], Awaitable[Outcome | None]]
MAX_BACKOFF_SECONDS = 300.0
# a stream of watch events delays a fleet's reconcile by at most this much (schedule_debounced)
DEFAULT_MAX_WAIT_SECONDS = 2.0


def backoff_delay(base: float, attempt: int, cap: float = MAX_BACKOFF_SECONDS) -> float:
    """Seconds before retry number ``attempt`` (0: the first retry): ``base`` doubling."""
    return float(min(cap, base * 2 ** max(0, min(attempt, 30))))


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
        self._locks: dict[FleetKey, asyncio.Lock] = {}
        self._timers: dict[FleetKey, asyncio.Task[None]] = {}
        self._failures: dict[FleetKey, int] = {}  # failed background runs in a row
        self._burst: dict[FleetKey, float] = {}  # when the pending debounced burst began
        self._users: dict[FleetKey, int] = {}  # holders and waiters of each fleet's lock
        self._forgotten: set[FleetKey] = set()  # locks to drop once their users left
        self.metrics: MetricsPort = metrics or NullMetrics()
        self.name = name
        self.metrics.init_controller(name)

    @contextlib.asynccontextmanager
    async def _locked(self, key: FleetKey) -> AsyncIterator[None]:
        """Hold the fleet's lock; the last user of a forgotten fleet's lock drops it."""
        lock = self._locks.setdefault(key, asyncio.Lock())
        self._users[key] = self._users.get(key, 0) + 1
        try:
            async with lock:
                yield
        finally:
            self._users[key] -= 1
            if not self._users[key]:
                del self._users[key]
                if key in self._forgotten:
                    self._forgotten.discard(key)
                    self._locks.pop(key, None)

    def forget(self, key: FleetKey) -> None:
        """The fleet is gone: drop its timer, burst, failures and (once unused) its lock."""
        self.cancel(key)
        self._failures.pop(key, None)
        self.metrics.forget_fleet(*key)
        if key in self._users:
            self._forgotten.add(key)
        else:
            self._locks.pop(key, None)

    def held(self) -> set[FleetKey]:
        """The fleets the queue holds anything for (a lock, a timer or failures)."""
        return set(self._locks) | set(self._timers) | set(self._failures)

    async def run_now(self, key: FleetKey) -> Outcome | None:
        self.cancel(key)
        self._forgotten.discard(key)  # a fleet created again under the same name
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
        self.cancel(key)
        wait = self.debounce if delay is None else delay
        self._timers[key] = asyncio.get_running_loop().create_task(self._later(key, wait))
        self.metrics.count_queue_add(self.name, retry)
        self._depth()

    def _depth(self) -> None:
        self.metrics.set_queue_depth(self.name, len(self._timers))

    def schedule_debounced(
        self, key: FleetKey, quiet: float | None = None, max_wait: float | None = None
    ) -> None:
        """Run ``quiet`` (default: the debounce) after the last of a burst of calls, at most
        ``max_wait`` (default: the queue's) after its first."""
        loop = asyncio.get_running_loop()
        now = loop.time()
        first = self._burst.get(key, now) if key in self._timers else now
        wait = self.debounce if quiet is None else quiet
        cap = self.max_wait if max_wait is None else max_wait
        self.schedule(key, max(0.0, min(wait, first + cap - now)))
        self._burst[key] = first

    def cancel(self, key: FleetKey) -> None:
        self._burst.pop(key, None)
        task = self._timers.pop(key, None)
        if task is not None and task is not asyncio.current_task():
            task.cancel()
        if task is not None:
            self._depth()

    def pending(self) -> set[FleetKey]:
        return set(self._timers)

    async def _later(self, key: FleetKey, wait: float) -> None:
        await asyncio.sleep(wait)
        if self._timers.get(key) is asyncio.current_task():
            del self._timers[key]
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
        self._failures.pop(key, None)
        self._follow_up(key, outcome)

    def _failed(self, key: FleetKey, reason: str) -> float:
        attempt = self._failures.get(key, 0)
        self._failures[key] = attempt + 1
        delay = backoff_delay(self.retry, attempt)
        self._error(key, reason)
        self.schedule(key, delay, retry=True)
        return delay

    def _follow_up(self, key: FleetKey, outcome: Outcome | None) -> None:
        if outcome is not None and outcome.requeue_after is not None and key not in self._timers:
            self.schedule(key, outcome.requeue_after)

    def _error(self, key: FleetKey, reason: str) -> None:
        if self.on_error is not None:
            self.on_error(key, reason)

    async def close(self) -> None:
        tasks = list(self._timers.values())
        self._timers.clear()
        self._depth()
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
