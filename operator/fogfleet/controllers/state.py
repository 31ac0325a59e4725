"""Everything the operator knows of each fleet: one ``FleetState`` per fleet, in one store.

The store is the controller's only memory between reconciles. Each field of ``FleetState``
says what it is:

- **cache**: rebuilt from the cluster after a restart or a failover (the new leader re-plans
  from the same inputs, finds the same fingerprint and keeps what runs). Losing it costs time,
  never correctness.
- **survives**: memory a failover must keep. fogfleet keeps none of it here: what must
  survive is written to the objects themselves (``status.scaling`` and the scaling state
  annotation of a SoftwareModule, ``status.profiling`` and ``status.profileCorrection``, the
  fleet's ``status`` with its conditions' transition times).

Forgetting a fleet is one ``FleetStore.forget``; the reconcile queue drops the fleet's lock
and timers in the same step (``ReconcileQueue.forget``).

The features that run beside the reconcile (link health, drift, usage) read what the last full
pass left for them (``LinkWatch``, ``DriftWatch``, ``placement``) and write only their own
part. They share this module, never each other. Modelled on the cache of kueue
(``pkg/cache/cache.go``): one struct per object, one lock over the map.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.linkhealth import LinkHealth
from fogfleet.api.v1alpha1.observed import DriftSettings
from fogfleet.controllers.stamp import DeploymentStamps
from fogfleet.domain.linkhealth import RobotLink
from fogfleet.domain.network import Link
from fogfleet.domain.observed import MissBudget, ModuleDrift
from fogfleet.domain.onboard import OnboardNeed
from fogfleet.domain.problem import Problem
from fogfleet.domain.takeovers import Mark, SeriesKey, Takeovers
from fogfleet.scheduling.decision import Decision
from fogfleet.snapshot.live import Live

__all__ = [
    "DriftWatch",
    "FleetDrift",
    "FleetKey",
    "FleetLinks",
    "FleetState",
    "FleetStore",
    "LinkWatch",
    "References",
    "Rendered",
    "RolloutProgress",
    "fleet_key",
]

FleetKey = tuple[str, str]  # (namespace, name)
Obj = dict[str, Any]


def fleet_key(body: Mapping[str, Any]) -> FleetKey:
    """(namespace, name) of a RobotFleet as the API server sends it."""
    meta = body.get("metadata") or {}
    return meta.get("namespace") or "default", meta["name"]


@dataclass(frozen=True)
class Rendered:
    """A full reconcile's result, kept for the status refreshes that follow it (cache)."""

    stamp: tuple[Any, ...]  # the inputs it was made from (stamp.input_stamp)
    at: float  # time.monotonic() of the full reconcile
    seconds: float  # how long it took (stamp.resync_overdue)
    problem: Problem
    desired: list[Obj]
    stranded: frozenset[int]
    plan: Decision | None
    baseline: bool
    measured: Mapping[str, Link] = field(default_factory=dict)  # robots planned around
    room: str = ""  # who else holds how many cores on its nodes (snapshot.room_note)


@dataclass(frozen=True)
class References:
    """What one fleet uses: a change to any of these re-plans it (cache)."""

    compute_nodes: frozenset[str] = frozenset()
    nodes: frozenset[str] = frozenset()  # Node names default to ComputeNode names
    modules: frozenset[str] = frozenset()
    selector: bool = False  # a selector fleet uses every ComputeNode and Node


@dataclass(frozen=True)
class LinkWatch:
    """What the link measurements need of a fleet, from its last full pass: robot
    ComputeNode -> (its Kubernetes Node, its declared uplink), its settings, its modules."""

    robots: Mapping[str, tuple[str, Link]]
    settings: LinkHealth | None
    modules: frozenset[str]

    @property
    def monitored(self) -> bool:
        return bool(self.robots) and self.settings is not None and self.settings.monitor


@dataclass
class FleetLinks:
    """The robots' links as measured, and what their standbys did (``measure/links.py``
    writes it; cache, re-measured, but for ``takeovers``)."""

    watch: LinkWatch | None = None
    robots: dict[str, RobotLink] = field(default_factory=dict)
    standbys_active: frozenset[tuple[str, str]] = frozenset()
    # (robot, module) -> what its standby did (domain.takeovers). Memory that must survive a
    # failover: it lives in status.fallbacks[].takeovers and is read back from there on the
    # first full pass (None until then)
    takeovers: dict[tuple[str, str], Takeovers] | None = None
    # the standbys' counters as last read (cache: None until the first reading, a baseline)
    marks: dict[SeriesKey, Mark] | None = None


@dataclass(frozen=True)
class DriftWatch:
    """What drift detection needs of a fleet, from its last full pass: its settings, the
    plan's predicted miss rate per module, one ComputeNode per hardware type (declared rows),
    the plan's problem and placement, and what each module can afford to miss above its
    prediction (its real-time class's share of the margin)."""

    settings: DriftSettings | None
    predicted: Mapping[str, float]
    hardware: Mapping[str, ComputeNode]
    problem: Problem
    placement: NDArray[np.int64] | None
    plan_id: str
    budgets: Mapping[str, MissBudget] = field(default_factory=dict)

    @property
    def enabled(self) -> bool:
        return self.settings is not None and self.settings.enabled and bool(self.predicted)


@dataclass
class FleetDrift:
    """Each module's measured against predicted misses (controllers/measure/observed.py; cache)."""

    watch: DriftWatch | None = None
    modules: dict[str, ModuleDrift] | None = None  # None: not measured yet
    # (plan id, when its measures began, the last re-plan for drift)
    epoch: tuple[str, float, float | None] | None = None
    # drifting module that cannot leave its robot -> per robot, what it needs there, the
    # robot shortest of CPU first (domain.onboard)
    onboard: dict[str, tuple[OnboardNeed, ...]] = field(default_factory=dict)


@dataclass
class RolloutProgress:
    """How the fleet's rollout goes, as the runtime counts it (cache)."""

    waiting: int | None = None  # modules still rolling out at the last count
    counted: float | None = None  # when (monotonic)
    eta: float | None = None  # seconds it needs at its pace (inf: no progress)
    # Deployments not yet running where planned (None: not refreshed yet)
    unsettled: frozenset[str] | None = None
    shown_ready: dict[str, float] = field(default_factory=dict)  # of those: ready since, when


@dataclass
class FleetState:
    """Everything the operator knows of one fleet (every field a cache; see the module)."""

    key: FleetKey
    references: References | None = None  # None until a reconcile recorded them
    plan: Decision | None = None  # the deployed plan, by input fingerprint
    # Kubernetes Node -> (CPU cores, memory bytes) the plan requests there: what the other
    # fleets plan around (controllers/fleet/tenancy.py); recorded with the plan, under the lock
    claims: dict[str, tuple[float, float]] = field(default_factory=dict)
    shared: list[Obj] = field(default_factory=list)  # status.sharedNodes of the plan
    failure: tuple[str, Exception] | None = None  # (fingerprint, the error it gave)
    rendered: Rendered | None = None
    # where its instances stand, as its last status refresh found them (the usage pass reads
    # it; replaced only when it changed, so a new object means a new placement)
    placement: list[Obj] | None = None
    deployment_stamps: DeploymentStamps = field(default_factory=DeploymentStamps)
    links: FleetLinks = field(default_factory=FleetLinks)
    drift: FleetDrift = field(default_factory=FleetDrift)
    rollout: RolloutProgress = field(default_factory=RolloutProgress)
    # Kubernetes Node -> why it is unavailable, as the last full pass saw the fleet's nodes
    # (node_events.py: a cache, so a restarted operator reports a node still down once more)
    unavailable: dict[str, str] = field(default_factory=dict)
    # its Deployments in managed clusters as last read from the OCM hub (kept while the hub
    # cannot be read: controllers/fleet/clusters.py)
    remote: list[Obj] = field(default_factory=list)
    # the plan that runs, as ExplanationRequests are answered from it (controllers/fleet/
    # explain.py): set by a full pass that applied it, kept when a later pass fails
    live: Live | None = None


class FleetStore:
    """The ``FleetState`` of every fleet the operator knows, under one lock.

    A fleet's own reconciles never overlap (the queue serialises them); the lock guards the
    map, which the reconciles, the periodic passes and the watch events share."""

    def __init__(self) -> None:
        self._states: dict[FleetKey, FleetState] = {}
        self._lock = threading.Lock()

    def state(self, key: FleetKey) -> FleetState:
        """The fleet's state, created empty for a fleet seen the first time."""
        with self._lock:
            found = self._states.get(key)
            if found is None:
                found = self._states[key] = FleetState(key)
            return found

    def get(self, key: FleetKey) -> FleetState | None:
        with self._lock:
            return self._states.get(key)

    def forget(self, key: FleetKey) -> None:
        """The fleet is gone: everything known of it goes with one delete."""
        with self._lock:
            self._states.pop(key, None)

    def states(self) -> list[FleetState]:
        """A snapshot of every fleet's state (the periodic passes iterate it)."""
        with self._lock:
            return list(self._states.values())

    def fleets(self) -> set[FleetKey]:
        """The fleets with recorded references (reconciled at least once)."""
        with self._lock:
            return {k for k, s in self._states.items() if s.references is not None}

    def using_compute_node(self, name: str) -> set[FleetKey]:
        return self._using(lambda r: name in r.compute_nodes)

    def using_node(self, name: str) -> set[FleetKey]:
        return self._using(lambda r: name in r.nodes)

    def using_module(self, namespace: str, name: str) -> set[FleetKey]:
        with self._lock:
            return {
                k
                for k, s in self._states.items()
                if k[0] == namespace and s.references is not None and name in s.references.modules
            }

    def _using(self, uses: Callable[[References], bool]) -> set[FleetKey]:
        with self._lock:
            return {
                k
                for k, s in self._states.items()
                if s.references is not None and (s.references.selector or uses(s.references))
            }
