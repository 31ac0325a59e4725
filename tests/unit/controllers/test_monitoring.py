"""Every fleet's Monitored condition: the operator's Prometheus, none, or not answering."""

from __future__ import annotations

from typing import Any

import pytest

from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.monitoring import MonitoredPrometheus, Monitoring
from fogfleet.errors import DependencyUnavailable, InvalidSpec

KEY = ("warehouse", "warehouse")
URL = "http://prometheus.monitoring:9090"


def run(kube: Any, deps: Any) -> None:
    reconcile(kube.get_fleet(*KEY), deps)


def monitored(kube: Any) -> dict[str, Any]:
    conditions = kube.fleets[KEY]["status"]["conditions"]
    return next(c for c in conditions if c["type"] == "Monitored")


class Port:
    """A Prometheus that answers, or not, or refuses a query."""

    def __init__(self) -> None:
        self.error: Exception | None = None

    def query_series(self, promql: str, *, obj: str = "", field: str = "") -> list[Any]:
        if self.error is not None:
            raise self.error
        return []

    def query_value(self, promql: str, *, obj: str = "", field: str = "") -> float | None:
        if self.error is not None:
            raise self.error
        return 1.0


def test_without_prometheus_the_fleet_says_what_is_off_and_how_to_turn_it_on(kube, deps) -> None:
    run(kube, deps)
    cond = monitored(kube)
    assert (cond["status"], cond["reason"]) == ("False", "NoPrometheus")
    for off in ("SLO scaling", "link health", "learnt profiles", "drift detection"):
        assert off in cond["message"]
    assert "scaling.prometheusUrl" in cond["message"]
    assert "FOGFLEET_PROMETHEUS_URL" in cond["message"]


def test_with_prometheus_the_fleet_is_monitored(kube) -> None:
    deps = Deps(kube=kube, monitoring=Monitoring(URL))
    run(kube, deps)
    cond = monitored(kube)
    assert (cond["status"], cond["reason"]) == ("True", "Prometheus")
    assert URL in cond["message"]


def test_a_prometheus_that_stops_answering_shows_until_it_answers_again(kube) -> None:
    monitoring = Monitoring(URL)
    deps = Deps(kube=kube, monitoring=monitoring)
    port = Port()
    prom = MonitoredPrometheus(port, monitoring)
    run(kube, deps)
    port.error = DependencyUnavailable("Cannot query Prometheus: connection refused")
    with pytest.raises(DependencyUnavailable):
        prom.query_series("up")
    run(kube, deps)
    cond = monitored(kube)
    assert (cond["status"], cond["reason"]) == ("False", "PrometheusUnreachable")
    assert "connection refused" in cond["message"] and URL in cond["message"]
    port.error = None
    assert prom.query_value("up") == 1.0
    run(kube, deps)
    assert monitored(kube)["reason"] == "Prometheus"
    assert monitoring.transitions == 2


def test_an_outage_keeps_the_error_it_began_with(kube) -> None:
    monitoring = Monitoring(URL)
    prom = MonitoredPrometheus(Port(), monitoring)
    prom._inner.error = DependencyUnavailable("first: refused")
    for _ in range(2):
        with pytest.raises(DependencyUnavailable):
            prom.query_series("up")
    prom._inner.error = DependencyUnavailable("second: timed out")
    with pytest.raises(DependencyUnavailable):
        prom.query_series("up")
    message = monitoring.condition(1)["message"]
    assert "first: refused" in message and "timed out" not in message
    assert monitoring.transitions == 1


def test_a_query_prometheus_refuses_is_an_answer(kube) -> None:
    monitoring = Monitoring(URL)
    monitoring.failed(DependencyUnavailable("refused"))
    port = Port()
    port.error = InvalidSpec("m", "spec.scaling.slo.query", "bad PromQL")
    with pytest.raises(InvalidSpec):
        MonitoredPrometheus(port, monitoring).query_value("rate(")
    assert monitoring.reachable


def test_the_condition_alone_writes_nothing_twice(kube, deps) -> None:
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    patches = len(kube.status_patches)
    run(kube, deps)
    assert len(kube.status_patches) == patches
    assert monitored(kube)["reason"] == "NoPrometheus"


def test_a_paused_fleet_says_it_too(kube, deps) -> None:
    kube.fleets[KEY]["spec"]["paused"] = True
    run(kube, deps)
    assert monitored(kube)["reason"] == "NoPrometheus"
    assert {c["type"] for c in kube.fleets[KEY]["status"]["conditions"]} == {
        "Scheduled",
        "Monitored",
    }
