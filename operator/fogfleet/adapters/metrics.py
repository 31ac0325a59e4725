"""The operator's own Prometheus metrics (prometheus-client), served on 127.0.0.1 by default.

fogfleet_plans_total{fleet,scheduler}              plans made (cache hits are not plans)
fogfleet_planning_seconds{scheduler}               planning duration histogram
fogfleet_objective{fleet,objective}                objective values of the last plan
fogfleet_degraded_instances{fleet}                 instances the last plan runs below their
                                                   deadline's CPU (0: not degraded)
fogfleet_migrations_total{fleet}                   running modules moved to another node
fogfleet_reconcile_errors_total{fleet,reason}      reconciles that failed, by error reason
fogfleet_deployments_applied_total{fleet}          Deployments applied (server-side)
fogfleet_deployments_pruned_total{fleet}           stale Deployments deleted
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server

__all__ = ["PrometheusMetrics"]

BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 20, 30, 60, 120)


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

    def serve(self, port: int, addr: str = "127.0.0.1") -> Any:
        """Start the /metrics HTTP server in a daemon thread; returns (server, thread)."""
        return start_http_server(port, addr=addr, registry=self.registry)

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
