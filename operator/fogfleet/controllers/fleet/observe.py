"""The observe step: the fleet object and what it depends on, read once and typed.

``FleetObject`` is what the reconcile keeps of the body the API server sent (no later step
reads the body). ``observe`` lists what a fleet's reconcile reads (its Deployments, the
namespace's SoftwareModules, the ComputeNodes and Nodes) and stamps it: an unchanged stamp
means only the rollout moved. ``parse`` turns those objects into the planning catalog, for
full passes only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from fogfleet.api.labels import LABEL_FLEET
from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.clusters import hub_nodes, remote_deployments
from fogfleet.controllers.fleet.engine import owned
from fogfleet.controllers.fleet.tenancy import claims_in
from fogfleet.controllers.stamp import input_stamp
from fogfleet.controllers.state import FleetKey, FleetState, References, fleet_key
from fogfleet.domain.fallback import variant_names
from fogfleet.domain.linkhealth import planned_links
from fogfleet.domain.network import Link
from fogfleet.domain.rows import Learnt
from fogfleet.domain.tenancy import Held
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import Owner, label_value
from fogfleet.render.wiring import is_ros_object
from fogfleet.snapshot import FleetSnapshot
from fogfleet.snapshot.catalog import Inputs, gather
from fogfleet.snapshot.clusters import managed_clusters_of, placed_in
from fogfleet.snapshot.objects import (
    current_placement,
    parse_fleet,
    profile_corrections,
    profiled,
    scaling_pools,
)
from fogfleet.snapshot.room import held_by_others, held_signature

__all__ = [
    "FleetInputs",
    "FleetObject",
    "Parsed",
    "fleet_snapshot",
    "observe",
    "parse",
    "parse_fleet",
    "record_references",
    "scaling_pools",
    "with_held_now",
]

Obj = dict[str, Any]


@dataclass(frozen=True)
class FleetObject:
    """What a reconcile keeps of the RobotFleet body: who it is and the status it had."""

    key: FleetKey
    uid: str | None
    generation: int | None
    old_status: Obj
    involved: Obj  # what its Events name (apiVersion, kind, metadata)

    @classmethod
    def read(cls, body: Mapping[str, Any]) -> FleetObject:
        meta = body.get("metadata") or {}
        key = fleet_key(body)
        involved = {
            "apiVersion": body.get("apiVersion"),
            "kind": body.get("kind"),
            "metadata": {
                "name": key[1],
                "namespace": key[0],
                "uid": meta.get("uid"),
                "resourceVersion": meta.get("resourceVersion"),
            },
        }
        status = dict(body.get("status") or {})
        return cls(key, meta.get("uid"), meta.get("generation"), status, involved)

    @property
    def owner(self) -> Owner | None:
        return Owner(self.key[1], self.uid) if self.uid else None

    @property
    def selector(self) -> dict[str, str]:
        """The fleet label of everything rendered for it."""
        return {LABEL_FLEET: label_value(self.key[1])}


@dataclass(frozen=True)
class FleetInputs:
    """Everything a fleet's reconcile reads from the cluster, and its stamp."""

    obj: FleetObject
    fleet: RobotFleet
    listed: list[Obj]  # the fleet's own Deployments (modules' and discovery servers')
    raw_modules: list[Obj]  # the namespace's SoftwareModules, with their status
    compute_nodes: list[Obj]
    nodes: list[Obj]
    measured: Mapping[str, Link]  # robots whose link is planned as measured, not declared
    corrections: dict[tuple[str, str], Learnt]  # profiles corrected by what ran
    held: Mapping[str, Held]  # Node -> what other tenants hold there (controllers/fleet/tenancy)
    stamp: tuple[Any, ...]
    hub_error: str = ""  # why the OCM hub was not read ("": it was, or no node needs it)

    @property
    def deployments(self) -> list[Obj]:
        """The modules' Deployments (not the discovery servers')."""
        return [d for d in self.listed if not is_ros_object(d)]


def observe(deps: Deps, state: FleetState, obj: FleetObject, fleet: RobotFleet) -> FleetInputs:
    """List what the fleet's reconcile reads and stamp it."""
    kube = deps.kube
    ns = obj.key[0]
    raw_modules = kube.list_modules(ns)
    compute_nodes, nodes = kube.list_compute_nodes(), kube.list_nodes()
    # a ComputeNode that stands for a managed cluster: its Node is what the hub says of it
    far, hub_error = hub_nodes(deps, compute_nodes)
    nodes = [*nodes, *far]
    # a robot's link measured worse than declared is planned with the measured figures
    measured = planned_links(state.links.robots)
    corrections = profile_corrections(raw_modules)
    inputs = FleetInputs(
        obj, fleet, [], raw_modules, compute_nodes, nodes, measured, corrections, {}, (), hub_error
    )
    return relisted(deps, state, with_held_now(deps, state, inputs))


def with_held_now(deps: Deps, state: FleetState, inputs: FleetInputs) -> FleetInputs:
    """``inputs`` with what the other tenants hold now (read again under the planning lock,
    so the plan sees every claim recorded before it)."""
    held = held_by_others(state.key, deps.kube.list_node_load(), claims_in(deps.store))
    return replace(inputs, held=held)


def relisted(deps: Deps, state: FleetState, inputs: FleetInputs) -> FleetInputs:
    """``inputs`` with the fleet's Deployments listed again (after an apply: what the next
    stamp sees), those in managed clusters read back from the hub, and its stamp."""
    obj = inputs.obj
    listed = [d for d in deps.kube.list_deployments(obj.key[0], obj.selector) if owned(d, obj.uid)]
    label = obj.selector[LABEL_FLEET]
    remote, hub_error = remote_deployments(
        deps, state, inputs.compute_nodes, obj.key[0], label, inputs.hub_error
    )
    listed += remote
    fleet_meta = {"metadata": {"uid": obj.uid, "generation": obj.generation}}
    stamp = (
        *input_stamp(
            fleet_meta,
            inputs.raw_modules,
            inputs.compute_nodes,
            inputs.nodes,
            listed,
            state.deployment_stamps,
        ),
        inputs.measured,
        (tuple(sorted(inputs.corrections.items())), profiled(inputs.raw_modules)),
        held_signature(inputs.held, state.references.nodes if state.references else None),
    )
    return replace(inputs, listed=listed, stamp=stamp, hub_error=hub_error)


@dataclass(frozen=True)
class Parsed:
    """The planning catalog a full pass plans from."""

    inputs: Inputs  # catalog, unavailable nodes, broken objects
    modules: dict[str, SoftwareModule]  # the namespace's, by name
    wanted: frozenset[str]  # the modules the fleet uses, with its standbys' variants
    pools: dict[str, dict[str, int]]  # the autoscaler's decisions

    @property
    def catalog(self) -> Catalog:
        return self.inputs.catalog


def parse(inputs: FleetInputs) -> Parsed:
    """The catalog of the fleet's inputs; InvalidSpec when the fleet references an invalid
    ComputeNode or SoftwareModule."""
    fleet = inputs.fleet
    gathered = gather(inputs.compute_nodes, inputs.raw_modules, inputs.nodes, inputs.held)
    ns = inputs.obj.key[0]
    modules = {
        m.metadata.name: m
        for m in gathered.catalog.modules.values()
        if (m.metadata.namespace or "default") == ns
    }
    # the variants the fleet's standbys run: a change to one (or its creation) re-plans it
    wanted = {m.name for m in fleet.spec.modules} | variant_names(fleet.spec, modules)
    _raise_broken_references(fleet, gathered.broken)
    return Parsed(gathered, modules, frozenset(wanted), scaling_pools(inputs.raw_modules))


def fleet_snapshot(
    inputs: FleetInputs, parsed: Parsed, released: frozenset[str] = frozenset()
) -> FleetSnapshot:
    """What the fleet plans from, as every entry point has it (``snapshot.FleetSnapshot``):
    the parsed catalog, unavailable nodes, current placement, pools, corrections, links
    planned as measured, the robots whose link recovered (``released``) and the room the
    other tenants hold."""
    return FleetSnapshot(
        key=inputs.obj.key,
        fleet=inputs.fleet,
        catalog=parsed.catalog,
        unavailable=parsed.inputs.unavailable,
        broken=parsed.inputs.broken,
        current=_current(inputs),
        pools=parsed.pools,
        corrections=inputs.corrections,
        measured_links=inputs.measured,
        released=released,
        held=inputs.held,
        status=inputs.obj.old_status,
    )


def _current(inputs: FleetInputs) -> dict[tuple[str, str, int], str]:
    """Where the fleet's instances run: its Deployments' nodes, and while the hub's works
    cannot be read, where its status last put those in managed clusters."""
    current = current_placement(inputs.deployments)
    if inputs.hub_error:
        clusters = managed_clusters_of(inputs.compute_nodes)
        for ident, node in placed_in(inputs.obj.old_status, clusters).items():
            current.setdefault(ident, node)
    return current


def record_references(
    state: FleetState,
    fleet: RobotFleet,
    modules: Iterable[str] | None = None,
    compute_nodes: Iterable[str] | None = None,
    nodes: Iterable[str] = (),
) -> None:
    """What the fleet uses, so a change to any of it re-checks the fleet."""
    names = set(compute_nodes if compute_nodes is not None else [])
    if compute_nodes is None:
        names = set(fleet.spec.robots) | set(fleet.spec.nodes)
    selector = fleet.spec.robot_selector is not None or fleet.spec.node_selector is not None
    wanted = modules if modules is not None else (m.name for m in fleet.spec.modules)
    state.references = References(
        frozenset(names), frozenset(set(nodes) | names), frozenset(wanted), selector
    )


def _raise_broken_references(fleet: RobotFleet, broken: dict[str, InvalidSpec]) -> None:
    wanted = [f"ComputeNode/{n}" for n in [*fleet.spec.robots, *fleet.spec.nodes]]
    wanted += [f"SoftwareModule/{m.name}" for m in fleet.spec.modules]
    for ref in wanted:
        if ref in broken:
            exc = broken[ref]
            raise InvalidSpec(
                f"RobotFleet/{fleet.metadata.name}",
                "spec",
                f"references {exc.obj}, which is invalid: {exc.field}: {exc.message}",
            )
