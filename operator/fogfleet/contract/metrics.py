"""The metrics contract: what a containerised ROS 2 module exports and what the operator reads.

One set of names serves the real workload, the twin (``fogfleet twin``) and the scaler, so a
dashboard or an SLO written against one works against all three.

==================================  =========  =======================================  ==========
metric                              type       labels                                   unit
==================================  =========  =======================================  ==========
fogfleet_cycle_time_seconds         histogram  module, robot, tier, hardware_type, cpu  seconds
fogfleet_missed_cycles_total        counter    module, robot, tier, hardware_type, cpu  cycles
fogfleet_execution_time_seconds     histogram  module, robot, tier, hardware_type, cpu  seconds
fogfleet_requests_served_total      counter    module, tier, privacy                    requests
fogfleet_requests_rejected_total    counter    module, privacy, reason                  requests
fogfleet_response_time_seconds      histogram  module, tier, privacy                    seconds
fogfleet_queue_length               gauge      module, tier                             requests
fogfleet_replicas                   gauge      module, tier, state                      replicas
==================================  =========  =======================================  ==========

Label values: ``module`` is the SoftwareModule's name; ``robot`` the robot's name; ``tier`` one
of ``robot``, ``edge``, ``cloud``; ``privacy`` ``private`` or ``normal``; ``reason`` (why a
request was rejected) ``slo`` (no tier could meet its target) or ``capacity`` (no replica at
all); ``state`` ``ready`` or ``starting``; ``hardware_type`` the node's hardware type and
``cpu`` the module's CPU limit in millicores (``100m``; empty without a limit), the key of
the profile row the cycle belongs to. ``namespace`` and ``pod`` are added by Prometheus'
Kubernetes service discovery, not by the exporter. ``module`` rather than ``service`` avoids
the label the Prometheus Operator itself attaches to every target.

``fogfleet_response_time_seconds`` is measured where the request is admitted and includes the
network round trip to the tier. ``fogfleet_requests_rejected_total`` has no ``tier`` label: a
rejected request was served by none. Offered load = served + rejected.

The operator's own metrics (its ``/metrics``, ``adapters.metrics``) follow the names
controller-runtime and client-go use, so the dashboards and alerts written for kubebuilder
operators fit fogfleet as they are; fogfleet's own names sit beside them:

==========================================  =========  ==========================  =========
metric                                      type       labels                      unit
==========================================  =========  ==========================  =========
controller_runtime_reconcile_total          counter    controller, result          reconciles
controller_runtime_reconcile_errors_total   counter    controller                  reconciles
controller_runtime_reconcile_time_seconds   histogram  controller                  seconds
workqueue_depth                             gauge      name                        objects
workqueue_adds_total                        counter    name                        adds
workqueue_retries_total                     counter    name                        retries
rest_client_requests_total                  counter    code, method, host          requests
fogfleet_watch_restarts_total               counter    kind, reason                restarts
fogfleet_plans_total                        counter    fleet, scheduler            plans
fogfleet_degraded_instances                 gauge      fleet                       instances
fogfleet_reconcile_errors_total             counter    fleet, reason               reconciles
==========================================  =========  ==========================  =========

``result`` is ``success``, ``error``, ``requeue`` or ``requeue_after`` (controller-runtime's);
``controller`` and ``name`` are the lower-case kind (``robotfleet``). ``code`` is the HTTP
status or ``<error>`` when no response came; ``method`` the HTTP verb (``PATCH``, ``POST``,
``DELETE``, ``GET``...); ``host`` the API server's host:port. controller-runtime has no
watch-restart metric (client-go's reflector metrics were removed), hence fogfleet's own:
``reason`` is ``expired`` (410 Gone: listed again), ``error`` (connection lost: watched again)
or ``unexpected`` (listed again after a bug).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from enum import StrEnum

__all__ = [
    "API_REQUESTS",
    "CYCLE_TIME",
    "EXECUTION_TIME",
    "HISTOGRAM_BUCKETS_SECONDS",
    "MISSED_CYCLES",
    "OPERATOR_METRICS",
    "QUEUE_LENGTH",
    "RECONCILE_ERRORS",
    "RECONCILE_TIME",
    "RECONCILE_TOTAL",
    "REPLICAS",
    "REQUESTS_REJECTED",
    "REQUESTS_SERVED",
    "RESPONSE_TIME",
    "WATCH_RESTARTS",
    "WORKLOAD_METRICS",
    "WORKQUEUE_ADDS",
    "WORKQUEUE_DEPTH",
    "WORKQUEUE_RETRIES",
    "Label",
    "histogram_of",
    "offered_rate_query",
    "selector",
    "slo_query",
]

CYCLE_TIME = "fogfleet_cycle_time_seconds"
EXECUTION_TIME = "fogfleet_execution_time_seconds"
MISSED_CYCLES = "fogfleet_missed_cycles_total"
REQUESTS_SERVED = "fogfleet_requests_served_total"
REQUESTS_REJECTED = "fogfleet_requests_rejected_total"
RESPONSE_TIME = "fogfleet_response_time_seconds"
QUEUE_LENGTH = "fogfleet_queue_length"
REPLICAS = "fogfleet_replicas"
WORKLOAD_METRICS = (
    CYCLE_TIME, MISSED_CYCLES, EXECUTION_TIME, REQUESTS_SERVED, REQUESTS_REJECTED,
    RESPONSE_TIME, QUEUE_LENGTH, REPLICAS,
)  # fmt: skip

# the operator's, in controller-runtime's and client-go's names (see the module docstring)
RECONCILE_TOTAL = "controller_runtime_reconcile_total"
RECONCILE_ERRORS = "controller_runtime_reconcile_errors_total"
RECONCILE_TIME = "controller_runtime_reconcile_time_seconds"
WORKQUEUE_DEPTH = "workqueue_depth"
WORKQUEUE_ADDS = "workqueue_adds_total"
WORKQUEUE_RETRIES = "workqueue_retries_total"
API_REQUESTS = "rest_client_requests_total"
WATCH_RESTARTS = "fogfleet_watch_restarts_total"
OPERATOR_METRICS = (
    RECONCILE_TOTAL, RECONCILE_ERRORS, RECONCILE_TIME, WORKQUEUE_DEPTH, WORKQUEUE_ADDS,
    WORKQUEUE_RETRIES, API_REQUESTS, WATCH_RESTARTS,
    "fogfleet_plans_total", "fogfleet_planning_seconds", "fogfleet_objective",
    "fogfleet_degraded_instances", "fogfleet_migrations_total", "fogfleet_reconcile_errors_total",
    "fogfleet_deployments_applied_total", "fogfleet_deployments_pruned_total",
)  # fmt: skip

# Bucket bounds chosen around robot control periods (10 ms - 1 s) and the tinyKube targets
# (0.35 s, 0.5 s) so that histogram_quantile interpolates inside a narrow bucket there.
HISTOGRAM_BUCKETS_SECONDS = (
    0.005, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.75, 1.0, 2.0, 5.0,
)  # fmt: skip


class Label(StrEnum):
    MODULE = "module"
    ROBOT = "robot"
    TIER = "tier"
    PRIVACY = "privacy"
    REASON = "reason"
    STATE = "state"
    NAMESPACE = "namespace"


def histogram_of(metric: str) -> str:
    """The contract histogram an SLO metric names (``api.v1alpha1.scaling.SloMetric``)."""
    return RESPONSE_TIME if metric == "responseTime" else CYCLE_TIME


_LABEL_NAME = re.compile(r"^[a-zA-Z_][a-zA-Z0-9_]*$")


def _quote(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def selector(labels: Mapping[str, str]) -> str:
    """A PromQL label matcher ``{a="x",b="y"}`` (sorted, values escaped)."""
    for name in labels:
        if not _LABEL_NAME.match(name):
            raise ValueError(f"{name!r} is not a Prometheus label name")
    return "{" + ",".join(f"{k}={_quote(v)}" for k, v in sorted(labels.items())) + "}"


def _window(seconds: int) -> str:
    if seconds < 1:
        raise ValueError("the rate window must be at least 1 second")
    return f"{seconds}s"


def slo_query(
    metric: str,
    *,
    module: str,
    namespace: str,
    percentile: int,
    window_seconds: int = 60,
    tier: str | None = None,
) -> str:
    """PromQL for the ``percentile``-th percentile of an SLO histogram, in seconds.

    ``sum by (le)`` aggregates the buckets of every pod (and, without ``tier``, every tier)
    before interpolating, which is the only correct way to get a quantile over replicas.
    """
    if not 0 < percentile < 100:
        raise ValueError(f"percentile must be between 1 and 99, got {percentile}")
    labels = {Label.MODULE.value: module, Label.NAMESPACE.value: namespace}
    if tier is not None:
        labels[Label.TIER.value] = tier
    buckets = f"{histogram_of(metric)}_bucket{selector(labels)}[{_window(window_seconds)}]"
    return f"histogram_quantile({percentile / 100:g}, sum by (le) (rate({buckets})))"


def offered_rate_query(
    *, module: str, namespace: str, privacy: str, window_seconds: int = 10
) -> str:
    """PromQL for the offered request rate (served + rejected) of one privacy class, req/s."""
    labels = selector(
        {Label.MODULE.value: module, Label.NAMESPACE.value: namespace, Label.PRIVACY.value: privacy}
    )
    window = _window(window_seconds)
    return (
        f"(sum(rate({REQUESTS_SERVED}{labels}[{window}])) or vector(0))"
        f" + (sum(rate({REQUESTS_REJECTED}{labels}[{window}])) or vector(0))"
    )
