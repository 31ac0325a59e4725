"""What a reconcile needs, injected (the composition root builds it; tests build fakes).

Also the in-memory state the controller keeps between reconciles: the plan cache (by input
fingerprint: same inputs, no re-plan) and the reference index (which fleets use which
ComputeNode, Kubernetes Node and SoftwareModule, so a change re-plans exactly those fleets).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fogfleet.adapters.ports import KubePort, MetricsPort, NullMetrics, Planner, Watches
from fogfleet.adapters.prometheus import PrometheusPort
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.linkhealth import LinkHealth
from fogfleet.api.v1alpha1.observed import DriftSettings
from fogfleet.controllers.planning import CorePlanner
from fogfleet.controllers.stamp import DeploymentStamps
from fogfleet.domain.linkhealth import RobotLink
from fogfleet.domain.network import Link
from fogfleet.domain.observed import ModuleDrift
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.schedule import Schedule

__all__ = [
    "CachedPlan",
    "Deps",
    "FleetKey",
    "References",
    "Rendered",
    "ScalingDeps",
    "ScalingKube",
    "fleet_key",
]

FleetKey = tuple[str, str]  # (namespace, name)
Obj = dict[str, Any]


def fleet_key(body: Mapping[str, Any]) -> FleetKey:
    """(namespace, name) of a RobotFleet as the API server sends it."""
    meta = body.get("metadata") or {}
    return meta.get("namespace") or "default", meta["name"]


@dataclass(frozen=True)
class CachedPlan:
    fingerprint: str
    schedule: Schedule
    placement: NDArray[np.int64]  # what was chosen (after the migration-margin rule)
    plan_id: str
    migrations: int
    choice_reason: str
    planned_at: str
    moves: tuple[str, ...] = ()  # "robot-1/module edge-1->edge-2" for the Migrated Event
    objectives: dict[str, float] = field(default_factory=dict)
    """The objectives of ``placement`` (the plan deployed), not of the solver's proposal."""


@dataclass(frozen=True)
class Rendered:
    """A full reconcile's result, kept for status refreshes."""

    stamp: tuple[Any, ...]
    at: float  # time.monotonic() of the full reconcile
    seconds: float  # how long it took (stamp.resync_overdue)
    problem: Problem
    desired: list[Obj]
    stranded: frozenset[int]
    plan: CachedPlan | None
    baseline: bool
    # what the link measurements need (controllers/links.py): robot ComputeNode -> (its
    # Kubernetes Node, its declared uplink); the fleet's settings; its module names
    robots: Mapping[str, tuple[str, Link]] = field(default_factory=dict)
    link_health: LinkHealth | None = None
    modules: frozenset[str] = frozenset()
    measured: Mapping[str, Link] = field(default_factory=dict)  # robots planned around
    # what drift detection needs (controllers/observed.py): the fleet's settings, the plan's
    # predicted miss rate per module, one ComputeNode per hardware type (declared rows)
    drift: DriftSettings | None = None
    predicted: Mapping[str, float] = field(default_factory=dict)
    hardware: Mapping[str, ComputeNode] = field(default_factory=dict)


@dataclass
class References:
    """Which fleets reference what. Selector fleets match every ComputeNode/Node."""

    compute_nodes: dict[FleetKey, set[str]] = field(default_factory=dict)
    nodes: dict[FleetKey, set[str]] = field(default_factory=dict)
    modules: dict[FleetKey, set[str]] = field(default_factory=dict)
    selectors: set[FleetKey] = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def record(
        self,
        key: FleetKey,
        compute_nodes: set[str],
        nodes: set[str],
        modules: set[str],
        selector: bool,
    ) -> None:
        with self.lock:
            self.compute_nodes[key] = compute_nodes
            self.nodes[key] = nodes | compute_nodes  # Node names default to ComputeNode names
            self.modules[key] = modules
            if selector:
                self.selectors.add(key)
            else:
                self.selectors.discard(key)

    def forget(self, key: FleetKey) -> None:
        with self.lock:
            for index in (self.compute_nodes, self.nodes, self.modules):
                index.pop(key, None)
            self.selectors.discard(key)

    def fleets(self) -> set[FleetKey]:
        with self.lock:
            return set(self.modules)

    def using_compute_node(self, name: str) -> set[FleetKey]:
        with self.lock:
            return {k for k, v in self.compute_nodes.items() if name in v} | set(self.selectors)

    def using_node(self, name: str) -> set[FleetKey]:
        with self.lock:
            return {k for k, v in self.nodes.items() if name in v} | set(self.selectors)

    def using_module(self, namespace: str, name: str) -> set[FleetKey]:
        with self.lock:
            return {k for k, v in self.modules.items() if k[0] == namespace and name in v}


@dataclass
class Deps:
    kube: KubePort
    planner: Planner = field(default_factory=CorePlanner)
    metrics: MetricsPort = field(default_factory=NullMetrics)
    plans: dict[FleetKey, CachedPlan] = field(default_factory=dict)
    rendered: dict[FleetKey, Rendered] = field(default_factory=dict)  # for status refreshes
    # where each fleet's instances stand, as its last status refresh found them (placement
    # entries; a large fleet's status does not list them): the usage pass reads these. An
    # entry is replaced only when it changed, so a new object means a new placement.
    placements: dict[FleetKey, list[Obj]] = field(default_factory=dict)
    # per fleet: its Deployments' part of the stamp, remembered object by object
    deployment_stamps: dict[FleetKey, DeploymentStamps] = field(default_factory=dict)
    refs: References = field(default_factory=References)
    failures: dict[FleetKey, tuple[str, Exception]] = field(default_factory=dict)  # fp -> error
    # operator-wide defaults for scheduler fields a fleet leaves out (FOGFLEET_SCHEDULER_*)
    scheduler_defaults: dict[str, int] = field(default_factory=dict)
    requeue_seconds: float = 2.0  # while pods are on their way
    retry_seconds: float = 10.0  # after DependencyUnavailable
    api_concurrency: int = 8  # a reconcile's independent writes (Deployments) in flight at once
    watches: Watches | None = None  # the caches behind ``kube``, when it reads from watches
    # a render is re-done once older than this (or than stamp.RESYNC_COST_FACTOR times what
    # it took; 0: every reconcile is a full pass)
    full_reconcile_seconds: float = 60.0
    # the robots' links as measured (controllers/links.py), and the standbys computing now
    links: dict[FleetKey, dict[str, RobotLink]] = field(default_factory=dict)
    standbys_active: dict[FleetKey, frozenset[tuple[str, str]]] = field(default_factory=dict)
    # per fleet: each module's measured against predicted misses (controllers/observed.py),
    # and (plan id, when its measures began, the last re-plan for drift)
    drift: dict[FleetKey, dict[str, ModuleDrift]] = field(default_factory=dict)
    drift_epoch: dict[FleetKey, tuple[str, float, float | None]] = field(default_factory=dict)


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
