"""What a reconcile needs, injected (the composition root builds it; tests build fakes): the
ports, the planner, the operator's settings and the store of every fleet's state
(``state.FleetStore``).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from fogfleet.adapters.ports import HubPort, KubePort, MetricsPort, NullMetrics, Watches
from fogfleet.adapters.prometheus import PrometheusPort
from fogfleet.controllers.monitoring import Monitoring
from fogfleet.controllers.state import FleetStore
from fogfleet.scheduling.decision import CorePlanner, Planner

__all__ = ["Deps", "Hub", "ScalingDeps", "ScalingKube"]

Obj = dict[str, Any]


@dataclass(frozen=True)
class Hub:
    """The Open Cluster Management hub the operator places managed clusters' instances
    through, and the name of its own cluster there (docs/multicluster.md)."""

    port: HubPort
    site: str
    namespaces: tuple[str, ...] = ()  # the site's namespaces this operator serves (): all
    # the ManagedClusters as last read: what the site knows of a cluster it cannot reach now
    # (its allocatable: the instances there are then stranded, not planned anew elsewhere)
    seen: dict[str, Obj] = field(default_factory=dict)
    # the site's Zenoh router, which the robots' relays dial (FOGFLEET_SITE_ROUTER; "": none,
    # and no ROS 2 message crosses to the clusters: render.relays)
    router: str = ""


@dataclass
class Deps:
    kube: KubePort
    planner: Planner = field(default_factory=CorePlanner)
    metrics: MetricsPort = field(default_factory=NullMetrics)
    store: FleetStore = field(default_factory=FleetStore)
    # operator-wide defaults for scheduler fields a fleet leaves out (FOGFLEET_SCHEDULER_*)
    scheduler_defaults: dict[str, int] = field(default_factory=dict)
    requeue_seconds: float = 2.0  # while pods are on their way
    retry_seconds: float = 10.0  # after DependencyUnavailable
    api_concurrency: int = 8  # a reconcile's independent writes (Deployments) in flight at once
    watches: Watches | None = None  # the caches behind ``kube``, when it reads from watches
    # a render is re-done once older than this (or than stamp.RESYNC_COST_FACTOR times what
    # it took; 0: every reconcile is a full pass)
    full_reconcile_seconds: float = 60.0
    # one fleet plans at a time, into what the others claimed (controllers/fleet/tenancy.py)
    planning: threading.Lock = field(default_factory=threading.Lock)
    # the operator's Prometheus as every fleet's Monitored condition tells it (none by default)
    monitoring: Monitoring = field(default_factory=Monitoring)
    # the OCM hub, for ComputeNodes with spec.managedCluster (None: such nodes are unavailable)
    hub: Hub | None = None


class ScalingKube(Protocol):
    """What the scaling controller needs from the API server (blocking calls)."""

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """One JSON merge patch of the SoftwareModule's status subresource."""
        ...

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None: ...

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None: ...


@dataclass
class ScalingDeps:
    kube: ScalingKube
    prometheus: PrometheusPort
    period_seconds: float = 15.0  # how often the timer decides (the HPA's sync period)
    slo_window_seconds: int = 60  # rate() window of the SLO histogram
    rate_window_seconds: int = 10  # rate() window of the offered load (predictive)
    cpu_window_seconds: int = 60
