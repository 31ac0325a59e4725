"""The runtime re-checks every fleet when its Prometheus starts or stops answering (so each
fleet's Monitored condition says so at once), once per change, not on every measurement."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from virtualtime import run_in_virtual_time

from fogfleet.controllers.deps import Deps
from fogfleet.controllers.monitoring import Monitoring
from fogfleet.controllers.state import References
from fogfleet.errors import DependencyUnavailable
from fogfleet.runtime.dispatch import Runtime

FLEETS = [("wh", "a"), ("wh", "b"), ("lab", "c")]
UNKNOWN = ("wh", "not-reconciled-yet")


def runtime_with_fleets() -> Runtime:
    runtime = Runtime(Deps(kube=object(), monitoring=Monitoring("http://prom:9090")), debounce=5)
    for key in FLEETS:  # reconciled once: their references are recorded
        runtime.store.state(key).references = References()
    runtime.store.state(UNKNOWN)  # known to the store, never reconciled
    return runtime


def drain(runtime: Runtime) -> set[Any]:
    """The fleets due for a re-check, then forgotten by the queue (as if re-checked)."""
    pending = runtime.queue.pending()
    for key in pending:
        runtime.queue.cancel(key)
    return pending


def test_each_change_of_prometheus_rechecks_every_reconciled_fleet_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async def main() -> list[set[Any]]:
        runtime = runtime_with_fleets()
        monitoring = runtime.deps.monitoring
        seen = []
        runtime._monitoring_moved()  # answering as at start: no news
        seen.append(drain(runtime))
        monitoring.failed(DependencyUnavailable("Cannot query Prometheus: refused"))
        runtime._monitoring_moved()
        seen.append(drain(runtime))
        monitoring.failed(DependencyUnavailable("still refused"))  # the same outage
        runtime._monitoring_moved()
        seen.append(drain(runtime))
        monitoring.answered()
        runtime._monitoring_moved()
        seen.append(drain(runtime))
        runtime._monitoring_moved()
        seen.append(drain(runtime))
        await runtime.close()
        return seen

    with caplog.at_level("INFO", logger="fogfleet.runtime.dispatch"):
        start, outage, same, back, after = run_in_virtual_time(main())
    assert start == set() and same == set() and after == set()
    assert outage == set(FLEETS) and back == set(FLEETS), "every reconciled fleet, once"
    said = [r.getMessage() for r in caplog.records]
    assert said == [
        "Prometheus does not answer: re-checking every fleet's Monitored condition",
        "Prometheus answers again: re-checking every fleet's Monitored condition",
    ]


def test_a_failing_measurement_rechecks_the_fleets_at_once() -> None:
    """The measuring loop: a round whose queries go unanswered re-checks every fleet after
    that round, without waiting for the drift timer; later failing rounds of the same outage
    re-check nothing more."""

    async def main() -> tuple[set[Any], int]:
        runtime = runtime_with_fleets()
        rounds = 0

        def measure(deps: Deps, port: Any, now: float) -> set[Any]:
            nonlocal rounds
            rounds += 1
            exc = DependencyUnavailable("Cannot query Prometheus: refused")
            deps.monitoring.failed(exc)
            raise exc

        loop = asyncio.create_task(runtime._measuring(0.01, measure, None, "the links"))
        for _ in range(500):  # real time: the round runs in a worker thread
            await asyncio.sleep(0.01)
            if runtime.queue.pending():
                break
        pending = drain(runtime)
        for _ in range(500):
            if rounds >= 3:
                break
            await asyncio.sleep(0.01)
        again = drain(runtime)
        loop.cancel()
        await asyncio.gather(loop, return_exceptions=True)
        await runtime.close()
        return pending | {("again", *k) for k in again}, rounds

    pending, rounds = asyncio.run(main())
    assert pending == set(FLEETS) and rounds >= 3
