"""The contract metrics (``fogfleet.contract.metrics``) of the simulated services.

The twin is one scrape target for many namespaces, so it sets ``namespace`` itself (on a real
cluster Prometheus' Kubernetes discovery adds it per pod). Counters of both privacy classes
start at 0 so that ``rate()`` sees the first requests.
"""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

from fogfleet.contract import metrics as contract

from .model import Rejected, Served

__all__ = ["TwinMetrics"]

PRIVACY = ("private", "normal")


class TwinMetrics:
    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry or CollectorRegistry()
        r = self.registry
        base = ["namespace", "module"]
        self.response = Histogram(
            contract.RESPONSE_TIME,
            "Admission to answer of a shared service's request, network round trip included.",
            [*base, "tier", "privacy"],
            buckets=contract.HISTOGRAM_BUCKETS_SECONDS,
            registry=r,
        )
        self.served = Counter(
            contract.REQUESTS_SERVED,
            "Requests a shared service answered.",
            [*base, "tier", "privacy"],
            registry=r,
        )
        self.rejected = Counter(
            contract.REQUESTS_REJECTED,
            "Requests admission turned away.",
            [*base, "privacy", "reason"],
            registry=r,
        )
        self.queue = Gauge(
            contract.QUEUE_LENGTH, "Requests waiting or in service.", [*base, "tier"], registry=r
        )
        self.replicas = Gauge(
            contract.REPLICAS, "Replicas per pool.", [*base, "tier", "state"], registry=r
        )

    def declare(self, namespace: str, module: str, tiers: Iterable[str]) -> None:
        """Create every series of a service at 0."""
        for privacy in PRIVACY:
            for reason in ("slo", "capacity"):
                self.rejected.labels(namespace, module, privacy, reason).inc(0)
            for tier in tiers:
                self.served.labels(namespace, module, tier, privacy).inc(0)

    def record(self, namespace: str, module: str, records: Iterable[Served | Rejected]) -> None:
        for rec in records:
            privacy = PRIVACY[0] if rec.private else PRIVACY[1]
            if isinstance(rec, Served):
                self.served.labels(namespace, module, rec.tier, privacy).inc()
                self.response.labels(namespace, module, rec.tier, privacy).observe(
                    rec.response_seconds
                )
            else:
                self.rejected.labels(namespace, module, privacy, rec.reason).inc()

    def pool(self, namespace: str, module: str, tier: str, ready: int, starting: int,
             in_system: int) -> None:  # fmt: skip
        self.replicas.labels(namespace, module, tier, "ready").set(ready)
        self.replicas.labels(namespace, module, tier, "starting").set(starting)
        self.queue.labels(namespace, module, tier).set(in_system)
