"""``FleetSnapshot``: all that one fleet's plan is made from, read once from the listed objects
(the API server's, or a folder's) and typed. Nothing after the snapshot reads a raw object.

Two ways in, one result: ``snapshot_of`` takes the objects as the API server lists them (the
operator, ``kubectl fogfleet``), ``snapshot_of_catalog`` the catalog a folder was read into
(``fogfleet plan DIR``, which has no Nodes, Deployments or status to read).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.placement import placement_entries_of
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.domain.network import Link
from fogfleet.domain.rows import Learnt
from fogfleet.domain.tenancy import Held, with_held
from fogfleet.errors import InvalidSpec

from .catalog import gather
from .objects import (
    Placement,
    current_placement,
    measured_rates,
    parse_fleet,
    profile_corrections,
    scaling_pools,
)
from .room import FleetKey

__all__ = ["FleetSnapshot", "Listed", "snapshot_of", "snapshot_of_catalog"]

Obj = dict[str, Any]


@dataclass(frozen=True)
class Listed:
    """The objects one fleet's plan reads, as the API server lists them."""

    fleet: Obj  # the RobotFleet, with its status
    compute_nodes: list[Obj]
    modules: list[Obj]  # the fleet namespace's SoftwareModules, with their status
    nodes: list[Obj]  # the Kubernetes Nodes
    # the fleet's module Deployments; None: not read, the status's placement says where its
    # instances run (``kubectl fogfleet`` on a fleet whose status lists it)
    deployments: list[Obj] | None = field(default_factory=list)


@dataclass(frozen=True)
class FleetSnapshot:
    """One fleet and the site around it, as it plans: the catalog (capacities from the Nodes,
    less the room others hold; modules with their profiled rows), the nodes it may not use
    and why, where its instances run, the autoscaler's pools, the profile corrections, the
    links planned as measured, the room held by others, and its rollout (what the status
    says is deployed, what was measured)."""

    key: FleetKey
    fleet: RobotFleet
    catalog: Catalog
    unavailable: Mapping[str, str] = field(default_factory=dict)  # ComputeNode -> why
    broken: Mapping[str, InvalidSpec] = field(default_factory=dict)  # "Kind/name" -> error
    current: Placement = field(default_factory=dict)  # the Deployments' node (or the status')
    pools: Mapping[str, Mapping[str, int]] = field(default_factory=dict)  # module -> tiers
    corrections: Mapping[tuple[str, str], Learnt] = field(default_factory=dict)
    measured_links: Mapping[str, Link] = field(default_factory=dict)  # robot -> as measured
    # robots planned with their declared link again after a spell planned as measured: their
    # instances are planned as if they did not run yet (``stickiness.release_robots``)
    released: frozenset[str] = frozenset()
    held: Mapping[str, Held] = field(default_factory=dict)  # Node -> held by others
    deployed: Placement = field(default_factory=dict)  # status.placement, else Deployments
    measured: Mapping[str, float] = field(default_factory=dict)  # module -> measured misses
    module_splits: Mapping[str, Any] = field(default_factory=dict)  # module -> status.split
    status: Mapping[str, Any] = field(default_factory=dict)  # the fleet's status as read
    listed: Listed | None = None  # the objects (a what-if changes them), None from a folder

    @property
    def name(self) -> str:
        """``namespace/name``, as every message names the fleet."""
        return f"{self.key[0]}/{self.key[1]}"


def snapshot_of(
    listed: Listed,
    held: Mapping[str, Held] | None = None,
    measured_links: Mapping[str, Link] | None = None,
) -> FleetSnapshot:
    """The fleet of ``listed`` and its site: ``held`` is what the other tenants hold on each
    Node (``room.held_by_others``), ``measured_links`` the robots whose link is planned as
    measured (``domain.linkhealth``)."""
    fleet = parse_fleet(listed.fleet)
    gathered = gather(listed.compute_nodes, listed.modules, listed.nodes, held)
    status = dict(listed.fleet.get("status") or {})
    deployed = _listed_placement(status)
    if listed.deployments is not None:
        current = current_placement(listed.deployments)
    elif fleet.spec.scheduler.algorithm is SchedulerName.K8S_DEFAULT:
        current = {}  # kube-scheduler binds its pods: no Deployment of it names a node
    else:
        current = deployed
    return FleetSnapshot(
        key=(fleet.metadata.namespace or "default", fleet.metadata.name),
        fleet=fleet,
        catalog=gathered.catalog,
        unavailable=dict(gathered.unavailable),
        broken=dict(gathered.broken),
        current=current,
        pools=scaling_pools(listed.modules),
        corrections=profile_corrections(listed.modules),
        measured_links=dict(measured_links or {}),
        held=dict(held or {}),
        deployed=deployed or current,
        measured=measured_rates(listed.fleet, listed.modules),
        module_splits={
            str(m["metadata"]["name"]): (m.get("status") or {}).get("split") for m in listed.modules
        },
        status=status,
        listed=listed,
    )


def snapshot_of_catalog(
    catalog: Catalog, fleet: RobotFleet, held: Mapping[str, Held] | None = None
) -> FleetSnapshot:
    """The fleet of a folder's ``catalog``, planned into what ``held`` leaves on each node
    (the fleets of the folder planned before it)."""
    if held:
        nodes = {name: with_held(cn, held.get(cn.node_name)) for name, cn in catalog.nodes.items()}
        catalog = dataclasses.replace(catalog, nodes=nodes)
    return FleetSnapshot(
        key=(fleet.metadata.namespace or "default", fleet.metadata.name),
        fleet=fleet,
        catalog=catalog,
        held=dict(held or {}),
    )


def _listed_placement(status: Mapping[str, Any]) -> Placement:
    """The status's placement (its list, or its compact form above the list's limit) by
    (robot, module, replica); empty when it has none (then the Deployments' node affinity
    says it)."""
    return {
        (e.get("robot") or "", e["module"], int(e.get("replica") or 0)): e["node"]
        for e in placement_entries_of(status)
        if e.get("node")
    }
