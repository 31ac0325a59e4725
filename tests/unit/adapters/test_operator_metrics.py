"""The operator's metrics in controller-runtime's and client-go's names move when they should:
reconciles by result, errors, durations, queue depth, adds and retries, watch restarts, API
requests by verb and code, and a fleet's status series (kept while it lives, gone after)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator, Mapping

import pytest
import urllib3
from kubernetes import client

from fogfleet.adapters.informer import Informer, WatchExpired
from fogfleet.adapters.kube import KubeClient
from fogfleet.adapters.metrics import PrometheusMetrics
from fogfleet.adapters.watched import WatchedKube
from fogfleet.contract.metrics import OPERATOR_METRICS
from fogfleet.controllers.outcome import Outcome
from fogfleet.errors import DependencyUnavailable
from fogfleet.runtime.queue import ReconcileQueue

KEY = ("ns", "fleet")


def sample(m: PrometheusMetrics, metric: str, **labels: str) -> float:
    return m.registry.get_sample_value(metric, labels) or 0.0


def test_every_operator_metric_of_the_contract_is_exported():
    m = PrometheusMetrics()
    m.init_controller("robotfleet")
    m.count_request("200", "GET", "h")
    m.count_watch_restart("Pod", "error")
    m.observe_plan("f", "nsga2", 0.1, {"missRate": 0.0})
    m.count_migrations("f", 1)
    m.count_error("f", "Infeasible")
    m.count_apply("f", 1, 1)
    exported = {s.name for metric in m.registry.collect() for s in metric.samples}
    for name in OPERATOR_METRICS:
        assert name in exported or f"{name}_count" in exported, name


def test_reconciles_are_counted_by_result_and_timed():
    m = PrometheusMetrics()
    outcomes = [Outcome(ready=True), Outcome(ready=False, requeue_after=60.0)]

    async def runner(key: tuple[str, str]) -> Outcome:
        if not outcomes:
            raise RuntimeError("boom")
        return outcomes.pop(0)

    async def main() -> None:
        q = ReconcileQueue(runner, debounce=0.0, metrics=m)
        assert sample(m, "controller_runtime_reconcile_errors_total", controller="robotfleet") == 0
        await q.run_now(KEY)
        await q.run_now(KEY)
        with pytest.raises(RuntimeError):
            await q.run_now(KEY)
        await q.close()

    asyncio.run(main())
    total = "controller_runtime_reconcile_total"
    assert sample(m, total, controller="robotfleet", result="success") == 1
    assert sample(m, total, controller="robotfleet", result="requeue_after") == 1
    assert sample(m, total, controller="robotfleet", result="error") == 1
    assert sample(m, "controller_runtime_reconcile_errors_total", controller="robotfleet") == 1
    count = "controller_runtime_reconcile_time_seconds_count"
    assert sample(m, count, controller="robotfleet") == 3


def test_queue_depth_adds_and_retries_follow_the_pending_runs():
    m = PrometheusMetrics()
    runs = 0

    async def runner(key: tuple[str, str]) -> Outcome:
        nonlocal runs
        runs += 1
        if runs == 1:
            raise DependencyUnavailable("API server", "down", reason="ApiUnavailable")
        return Outcome(ready=True)

    async def main() -> list[float]:
        q = ReconcileQueue(runner, debounce=0.05, retry=0.01, metrics=m)
        q.schedule(("ns", "a"))
        q.schedule(("ns", "b"))
        depth = [sample(m, "workqueue_depth", name="robotfleet")]
        await asyncio.sleep(0.3)
        depth.append(sample(m, "workqueue_depth", name="robotfleet"))
        await q.close()
        return depth

    depth = asyncio.run(main())
    assert depth == [2, 0]
    assert sample(m, "workqueue_adds_total", name="robotfleet") == 3  # two, and one retry
    assert sample(m, "workqueue_retries_total", name="robotfleet") == 1


class Flaky:
    """A WatchSource whose watches expire once, then lose the connection, then stay quiet."""

    def __init__(self) -> None:
        self.watches: list[Exception] = [
            WatchExpired("gone"),
            DependencyUnavailable("Cannot watch: reset"),
        ]
        self.done = threading.Event()

    def list_versioned(self, path: str, selector: Mapping[str, str] | None) -> tuple[list, str]:
        return [], "10"

    def watch(self, path: str, selector, version: str, seconds: int) -> Iterator[dict]:
        if not self.watches:
            self.done.set()
            time.sleep(60)
            return
        raise self.watches.pop(0)
        yield {}


def test_watch_restarts_are_counted_by_kind_and_reason():
    m = PrometheusMetrics()
    source = Flaky()
    informer = Informer(source, "/api/v1/pods", kind="Pod", on_restart=m.count_watch_restart)
    informer.start()
    assert source.done.wait(5)
    informer.stop()
    restarts = "fogfleet_watch_restarts_total"
    assert sample(m, restarts, kind="Pod", reason="expired") == 1
    assert sample(m, restarts, kind="Pod", reason="error") == 1


def test_the_watched_client_reports_its_informers_restarts_by_kind():
    m = PrometheusMetrics()
    kube = WatchedKube(client.ApiClient(client.Configuration()), namespaces=["a"], metrics=m)
    kinds = {i.kind for i in kube.informers()}
    assert kinds == {"Node", "ComputeNode", "SoftwareModule", "Deployment", "Pod"}
    assert all(i.on_restart is not None for i in kube.informers())


class Response:
    def __init__(self, status: int) -> None:
        self.status = status

    def read(self) -> bytes:
        return b"{}"


def test_api_requests_are_counted_by_code_method_and_host(monkeypatch):
    m = PrometheusMetrics()
    cfg = client.Configuration(host="https://10.96.0.1:443")
    kube = KubeClient(client.ApiClient(cfg), metrics=m)
    answers: list[object] = [Response(200), Response(404), urllib3.exceptions.ProtocolError("x")]

    def call_api(*args: object, **kwargs: object) -> Response:
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        assert isinstance(answer, Response)
        return answer

    monkeypatch.setattr(kube.api, "call_api", call_api)
    kube.patch_fleet_status("ns", "f", {"observedGeneration": 1})
    kube.delete_service("ns", "gone")
    with pytest.raises(DependencyUnavailable):
        kube.patch_fleet_status("ns", "f", {"observedGeneration": 2})
    requests = "rest_client_requests_total"
    host = "10.96.0.1:443"
    assert sample(m, requests, code="200", method="PATCH", host=host) == 1
    assert sample(m, requests, code="404", method="DELETE", host=host) == 1
    assert sample(m, requests, code="<error>", method="PATCH", host=host) == 1


def test_a_fleets_status_series_follow_its_conditions_and_go_with_it():
    m = PrometheusMetrics()
    status = {
        "conditions": [
            {"type": "Ready", "status": "False"},
            {"type": "Drift", "status": "True"},
        ],
        "links": [
            {"robot": "r1", "state": "Lost", "standbysActive": ["slam", "nav"]},
            {"robot": "r2", "state": "Healthy"},
        ],
    }
    m.observe_fleet_status("ns", "f", status)
    cond = "fogfleet_fleet_condition"
    labels = {"fleet_namespace": "ns", "fleet": "f"}
    assert sample(m, cond, **labels, type="Ready", status="False") == 1
    assert sample(m, cond, **labels, type="Ready", status="True") == 0
    links = "fogfleet_fleet_robot_links"
    assert sample(m, links, **labels, state="Lost") == 1
    assert sample(m, links, **labels, state="Degraded") == 0
    assert sample(m, "fogfleet_fleet_fallbacks_active", **labels) == 2
    # the Drift condition went away (drift no longer watched): its series too
    m.observe_fleet_status("ns", "f", {"conditions": [{"type": "Ready", "status": "True"}]})
    get = m.registry.get_sample_value
    assert get(cond, {**labels, "type": "Drift", "status": "True"}) is None
    assert sample(m, cond, **labels, type="Ready", status="True") == 1
    m.forget_fleet("ns", "f")
    assert get(cond, {**labels, "type": "Ready", "status": "True"}) is None
    assert get(links, {**labels, "state": "Lost"}) is None


def test_forgetting_a_fleet_in_the_queue_drops_its_status_series():
    m = PrometheusMetrics()

    async def runner(key: tuple[str, str]) -> Outcome:
        return Outcome(ready=True)

    q = ReconcileQueue(runner, metrics=m)
    m.observe_fleet_status(*KEY, {"conditions": [{"type": "Ready", "status": "True"}]})
    q.forget(KEY)
    labels = {"fleet_namespace": "ns", "fleet": "fleet", "type": "Ready", "status": "True"}
    assert m.registry.get_sample_value("fogfleet_fleet_condition", labels) is None
