"""The operator's own Prometheus metrics (prometheus-client), served on 127.0.0.1 by default.

fogfleet's own:

fogfleet_plans_total{fleet,scheduler}              plans made (cache hits are not plans)
fogfleet_planning_seconds{scheduler}               planning duration histogram
fogfleet_objective{fleet,objective}                objective values of the last plan
fogfleet_degraded_instances{fleet}                 instances the last plan runs below their
                                                   deadline's CPU (0: not degraded)
fogfleet_migrations_total{fleet}                   running modules moved to another node
fogfleet_reconcile_errors_total{fleet,reason}      reconciles that failed, by error reason
fogfleet_deployments_applied_total{fleet}          Deployments applied (server-side)
fogfleet_deployments_pruned_total{fleet}           stale Deployments deleted
fogfleet_fleet_condition{fleet_namespace,fleet,type,status}
                                                   1 for each condition's status, 0 for the
                                                   other two (kube-state-metrics' form)
fogfleet_fleet_robot_links{fleet_namespace,fleet,state}
                                                   robots whose link is in each state
fogfleet_fleet_fallbacks_active{fleet_namespace,fleet}
                                                   on-board standbys computing now
fogfleet_watch_restarts_total{kind,reason}         informer watches restarted

and controller-runtime's and client-go's names (``contract.metrics`` lists them with their
labels): ``controller_runtime_reconcile_total``, ``controller_runtime_reconcile_errors_total``,
``controller_runtime_reconcile_time_seconds``, ``workqueue_depth``, ``workqueue_adds_total``,
``workqueue_retries_total`` and ``rest_client_requests_total``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server

__all__ = ["CONDITION_STATUSES", "LINK_STATES", "RECONCILE_BUCKETS", "PrometheusMetrics"]

BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 20, 30, 60, 120)
# controller-runtime's reconcile-time buckets, thinned: 5 ms to 60 s
RECONCILE_BUCKETS = (
    0.005, 0.01, 0.025, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0,
    5.0, 7.5, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0,
)  # fmt: skip
CONDITION_STATUSES = ("True", "False", "Unknown")
LINK_STATES = ("Healthy", "Degraded", "Recovering", "Lost", "Unknown")  # domain.linkhealth


class PrometheusMetrics:
    """MetricsPort on its own registry (so several operators can live in one test process)."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry or CollectorRegistry()
        r = self.registry
        self.plans = Counter("fogfleet_plans", "Plans made.", ["fleet", "scheduler"], registry=r)
        self.planning = Histogram(
            "fogfleet_planning_seconds",
            "Planning duration.",
            ["scheduler"],
            buckets=BUCKETS,
            registry=r,
        )
        self.objective = Gauge(
            "fogfleet_objective",
            "Objective values of the last plan.",
            ["fleet", "objective"],
            registry=r,
        )
        self.degraded = Gauge(
            "fogfleet_degraded_instances",
            "Instances the last plan runs below the CPU their deadline needs (0: not degraded).",
            ["fleet"],
            registry=r,
        )
        self.migrations = Counter(
            "fogfleet_migrations", "Running modules moved to another node.", ["fleet"], registry=r
        )
        self.errors = Counter(
            "fogfleet_reconcile_errors", "Reconciles that failed.", ["fleet", "reason"], registry=r
        )
        self.applied = Counter(
            "fogfleet_deployments_applied", "Deployments applied.", ["fleet"], registry=r
        )
        self.pruned = Counter(
            "fogfleet_deployments_pruned", "Stale Deployments deleted.", ["fleet"], registry=r
        )
        fleet = ["fleet_namespace", "fleet"]
        self.conditions = Gauge(
            "fogfleet_fleet_condition",
            "A fleet's conditions: 1 for the status each has, 0 for the other two.",
            [*fleet, "type", "status"],
            registry=r,
        )
        self.links = Gauge(
            "fogfleet_fleet_robot_links",
            "Robots of a fleet whose link is in each state (fleets whose links are monitored).",
            [*fleet, "state"],
            registry=r,
        )
        self.fallbacks = Gauge(
            "fogfleet_fleet_fallbacks_active",
            "On-board standbys computing their module's outputs now.",
            fleet,
            registry=r,
        )
        self._condition_types: dict[tuple[str, str], set[str]] = {}
        # controller-runtime's and client-go's names
        self.reconciles = Counter(
            "controller_runtime_reconcile",
            "Total number of reconciliations per controller.",
            ["controller", "result"],
            registry=r,
        )
        self.reconcile_errors = Counter(
            "controller_runtime_reconcile_errors",
            "Total number of reconciliation errors per controller.",
            ["controller"],
            registry=r,
        )
        self.reconcile_time = Histogram(
            "controller_runtime_reconcile_time_seconds",
            "Length of time per reconciliation per controller.",
            ["controller"],
            buckets=RECONCILE_BUCKETS,
            registry=r,
        )
        self.depth = Gauge("workqueue_depth", "Current depth of workqueue.", ["name"], registry=r)
        self.adds = Counter(
            "workqueue_adds", "Total number of adds handled by workqueue.", ["name"], registry=r
        )
        self.retries = Counter(
            "workqueue_retries", "Total number of retries handled by workqueue.", ["name"],
            registry=r,
        )  # fmt: skip
        self.requests = Counter(
            "rest_client_requests",
            "Number of HTTP requests, partitioned by status code, method, and host.",
            ["code", "method", "host"],
            registry=r,
        )
        self.watch_restarts = Counter(
            "fogfleet_watch_restarts",
            "Informer watches restarted: expired (listed again), error (watched again after a "
            "lost connection), unexpected (listed again after a bug).",
            ["kind", "reason"],
            registry=r,
        )

    def serve(self, port: int, addr: str = "127.0.0.1") -> Any:
        """Start the /metrics HTTP server in a daemon thread; returns (server, thread)."""
        return start_http_server(port, addr=addr, registry=self.registry)

    # ------------------------------------------------------------------ planning and applying
    def observe_plan(
        self,
        fleet: str,
        scheduler: str,
        seconds: float,
        objectives: Mapping[str, float],
        degraded: int = 0,
    ) -> None:
        self.plans.labels(fleet, scheduler).inc()
        self.planning.labels(scheduler).observe(seconds)
        for name, value in objectives.items():
            self.objective.labels(fleet, name).set(value)
        self.degraded.labels(fleet).set(degraded)

    def count_migrations(self, fleet: str, n: int) -> None:
        if n:
            self.migrations.labels(fleet).inc(n)

    def count_error(self, fleet: str, reason: str) -> None:
        self.errors.labels(fleet, reason).inc()

    def count_apply(self, fleet: str, applied: int, pruned: int) -> None:
        if applied:
            self.applied.labels(fleet).inc(applied)
        if pruned:
            self.pruned.labels(fleet).inc(pruned)

    # ------------------------------------------------------------------ a fleet's status
    def observe_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """The fleet's conditions, robots' link states and active standbys, from its status."""
        types: set[str] = set()
        for cond in status.get("conditions") or []:
            kind, now = str(cond.get("type")), str(cond.get("status"))
            types.add(kind)
            for st in CONDITION_STATUSES:
                self.conditions.labels(namespace, name, kind, st).set(1 if st == now else 0)
        for gone in self._condition_types.get((namespace, name), set()) - types:
            for st in CONDITION_STATUSES:
                self._remove(self.conditions, namespace, name, gone, st)
        self._condition_types[(namespace, name)] = types
        links = status.get("links") or []
        for state in LINK_STATES:
            count = sum(1 for e in links if e.get("state") == state)
            self.links.labels(namespace, name, state).set(count)
        active = sum(len(e.get("standbysActive") or []) for e in links)
        self.fallbacks.labels(namespace, name).set(active)

    def forget_fleet(self, namespace: str, name: str) -> None:
        """The fleet is gone: its status series go (an alert must not fire for it forever)."""
        for kind in self._condition_types.pop((namespace, name), set()):
            for st in CONDITION_STATUSES:
                self._remove(self.conditions, namespace, name, kind, st)
        for state in LINK_STATES:
            self._remove(self.links, namespace, name, state)
        self._remove(self.fallbacks, namespace, name)

    @staticmethod
    def _remove(metric: Gauge, *labels: str) -> None:
        with contextlib.suppress(KeyError):
            metric.remove(*labels)

    # ------------------------------------------------------------------ controller-runtime's
    def init_controller(self, controller: str) -> None:
        """Zero series for a controller (as controller-runtime does at start), so a rate()
        or an alert on errors has a series to read before the first error."""
        for result in ("success", "error", "requeue", "requeue_after"):
            self.reconciles.labels(controller, result)
        self.reconcile_errors.labels(controller)
        self.reconcile_time.labels(controller)
        self.depth.labels(controller).set(0)
        self.adds.labels(controller)
        self.retries.labels(controller)

    def observe_reconcile(self, controller: str, result: str, seconds: float) -> None:
        """One reconcile: its result (success, error, requeue, requeue_after) and duration."""
        self.reconciles.labels(controller, result).inc()
        if result == "error":
            self.reconcile_errors.labels(controller).inc()
        self.reconcile_time.labels(controller).observe(seconds)

    def set_queue_depth(self, name: str, depth: int) -> None:
        self.depth.labels(name).set(depth)

    def count_queue_add(self, name: str, retry: bool = False) -> None:
        self.adds.labels(name).inc()
        if retry:
            self.retries.labels(name).inc()

    # ------------------------------------------------------------------ client-go's
    def count_request(self, code: str, method: str, host: str) -> None:
        self.requests.labels(code, method, host).inc()

    def init_watch(self, kind: str) -> None:
        """Zero restart series for a kind (so its panel and rate() have a series at once)."""
        for reason in ("expired", "error", "unexpected"):
            self.watch_restarts.labels(kind, reason)

    def count_watch_restart(self, kind: str, reason: str) -> None:
        self.watch_restarts.labels(kind, reason).inc()
