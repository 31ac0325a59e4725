"""Whether the operator's measuring loops run, said in every fleet's ``Monitored`` condition
(issue 44).

SLO scaling of shared modules, link health, learnt profiles (``status.profileCorrection``) and
drift detection all read Prometheus (FOGFLEET_PROMETHEUS_URL, the chart's
``scaling.prometheusUrl``). An operator installed without one plans and places fleets as
usual, but none of those four runs: the start-up log says so once, and every fleet's status
says so for as long as it lasts, naming what is off and how to turn it on. With a URL, the
Prometheus port is wrapped (:class:`MonitoredPrometheus`) so that every query tells
:class:`Monitoring` whether Prometheus answered; a fleet then shows ``PrometheusUnreachable``
while it does not.

The condition's message changes only when the state does (an outage keeps the error it began
with), so a status refresh finds nothing new and writes nothing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

from fogfleet.adapters.prometheus import QUERY_FIELD, PrometheusPort
from fogfleet.controllers.status import condition
from fogfleet.errors import DependencyUnavailable, FogfleetError

__all__ = [
    "CONDITION",
    "MEASURED_LOOPS",
    "REASON_NO_PROMETHEUS",
    "REASON_PROMETHEUS",
    "REASON_UNREACHABLE",
    "MonitoredPrometheus",
    "Monitoring",
]

T = TypeVar("T")
Obj = dict[str, Any]

CONDITION = "Monitored"
REASON_PROMETHEUS = "Prometheus"
REASON_NO_PROMETHEUS = "NoPrometheus"
REASON_UNREACHABLE = "PrometheusUnreachable"
MEASURED_LOOPS = (
    "SLO scaling of shared modules, link health (status.links), learnt profiles "
    "(SoftwareModule status.profileCorrection) and drift detection (status.measured, the "
    "Drift condition)"
)
HOW_TO_TURN_ON = (
    "set scaling.prometheusUrl in the Helm chart (env FOGFLEET_PROMETHEUS_URL) to a "
    "Prometheus that scrapes the modules' pods"
)
ERROR_CHARS = 300  # of the error an outage began with, in the message


class Monitoring:
    """The operator's Prometheus as the fleets' status tells it: none, answering, or not
    answering since some error. Shared by the measuring loops (which report each query) and
    every fleet's reconcile (which reads the condition); ``transitions`` counts the changes,
    so the runtime re-checks the fleets when it moves."""

    def __init__(self, url: str | None = None) -> None:
        self.url = url
        self._error: str | None = None  # the error the current outage began with
        self._lock = threading.Lock()
        self.transitions = 0

    @property
    def reachable(self) -> bool:
        """A URL is set and its last query was answered (or none was made yet)."""
        with self._lock:
            return self.url is not None and self._error is None

    def answered(self) -> None:
        """A query was answered (even one Prometheus refused as bad PromQL)."""
        with self._lock:
            if self._error is not None:
                self._error = None
                self.transitions += 1

    def failed(self, exc: Exception) -> None:
        """A query got no answer: an outage begins, unless one already runs."""
        with self._lock:
            if self._error is None:
                self._error = str(exc)[:ERROR_CHARS]
                self.transitions += 1

    def condition(self, generation: int | None) -> Obj:
        """The ``Monitored`` condition of a fleet (see the module docstring)."""
        with self._lock:
            url, error = self.url, self._error
        if url is None:
            message = (
                f"The operator has no Prometheus, so {MEASURED_LOOPS} are off: {HOW_TO_TURN_ON}"
            )
            return condition(CONDITION, False, REASON_NO_PROMETHEUS, message, generation)
        if error is not None:
            message = (
                f"Prometheus at {url} does not answer ({error}): {MEASURED_LOOPS} are paused "
                "and their last states stand until it answers again"
            )
            return condition(CONDITION, False, REASON_UNREACHABLE, message, generation)
        message = f"Prometheus at {url} feeds {MEASURED_LOOPS}"
        return condition(CONDITION, True, REASON_PROMETHEUS, message, generation)


class MonitoredPrometheus:
    """A Prometheus port (``PrometheusPort`` and ``SeriesPort``) that reports every query to
    ``monitoring``: ``DependencyUnavailable`` is an outage, anything else an answer."""

    def __init__(self, inner: Any, monitoring: Monitoring) -> None:
        self._inner = inner
        self._monitoring = monitoring

    def query_value(self, promql: str, *, obj: str = "", field: str = QUERY_FIELD) -> float | None:
        port: PrometheusPort = self._inner
        return self._watched(lambda: port.query_value(promql, obj=obj, field=field))

    def query_series(
        self, promql: str, *, obj: str = "", field: str = ""
    ) -> list[tuple[dict[str, str], float]]:
        return self._watched(lambda: self._inner.query_series(promql, obj=obj, field=field))

    def _watched(self, query: Callable[[], T]) -> T:
        try:
            out = query()
        except DependencyUnavailable as exc:
            self._monitoring.failed(exc)
            raise
        except FogfleetError:
            self._monitoring.answered()  # it answered: the query or its result was wrong
            raise
        self._monitoring.answered()
        return out
