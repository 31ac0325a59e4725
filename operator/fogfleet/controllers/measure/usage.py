"""Status of the shared kinds: which fleets use a SoftwareModule or a ComputeNode, and how many
instances run where.

Everything is derived from the plans actually deployed: each fleet's placement as its last
status refresh found it (``FleetState.placement``), or, for a fleet this process has not reconciled
yet, its status's placement (``status.placement``, or ``status.placementCompact`` for a fleet
of more than ``PLACEMENT_LIST_LIMIT`` instances). So it needs no
state of its own and any replica of the operator can rebuild it. One pass
(``reconcile_usage``) lists the fleets, modules, ComputeNodes and Nodes
and patches only the statuses that changed; each patch carries every field this pass owns
(``None`` for a measured miss rate no longer measured, which the merge patch removes), so a
merge patch never leaves a stale value behind. A module's measured miss rate
(``status.measuredMissRate``, the MEASURED column) pools its fleets' measures, each weighed by
its cycles: the drift pass's (``FleetState.drift``, fresher; the runtime runs a pass when they
change) or, for a fleet it has not measured, the fleet's ``status.measured``. A fleet being deleted
(``deletionTimestamp`` set, its Deployments going) counts no more, and a deleted one is not
listed: the first pass after a fleet's deletion drops it from every node and module it used
(the runtime runs one when the fleet's DELETED event arrives). The autoscaler owns
``status.scaling`` and the ``Scaling``/``MetricsUnavailable`` conditions of a module; this
pass never writes them.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from fogfleet.api.v1alpha1.base import format_cores, parse_cpu
from fogfleet.api.v1alpha1.computenode import ComputeNodeStatus
from fogfleet.api.v1alpha1.placement import placement_entries_of
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModuleStatus, Taxonomy
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.clusters import hub_nodes
from fogfleet.controllers.status import (
    condition,
    merge_conditions,
    miss_fields,
    split_text,
    wire,
    without_transition_times,
)
from fogfleet.domain.miss_rates import pooled_miss_rate
from fogfleet.domain.taxonomy import classify
from fogfleet.domain.tenancy import Held
from fogfleet.snapshot.objects import node_health, written_status
from fogfleet.snapshot.room import pod_requests

__all__ = [
    "Usage",
    "compute_node_status",
    "module_status",
    "reconcile_usage",
    "usage_by_module",
    "usage_by_node",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


@dataclass
class Usage:
    """Who places instances of one object, and where; for a module, its measured miss rate
    in each fleet that measured it, with the cycles behind it."""

    fleets: set[str] = field(default_factory=set)
    tiers: Counter[str] = field(default_factory=Counter)
    cpu: float = 0.0
    measured: list[tuple[float | None, float]] = field(default_factory=list)

    @property
    def instances(self) -> int:
        return sum(self.tiers.values())


Placements = Mapping[tuple[str, str], list[Obj]]
# (namespace, fleet) -> module -> its measured miss rate there (None: not measured) and cycles
Measures = Mapping[tuple[str, str], Mapping[str, tuple[float | None, float]]]


def _placements(
    fleets: Iterable[Mapping[str, Any]], known: Placements
) -> Iterable[tuple[str, str, Obj]]:
    for fleet in fleets:
        meta = fleet.get("metadata") or {}
        if meta.get("deletionTimestamp"):
            continue  # going: what it placed is being deleted with it
        key = (meta.get("namespace") or "default", meta.get("name", ""))
        entries = known.get(key)
        if entries is None:
            entries = placement_entries_of(fleet.get("status") or {})
        for entry in entries:
            yield key[0], key[1], entry


def _cores(value: Any) -> float:
    try:
        return parse_cpu(value) if value not in (None, "") else 0.0
    except ValueError:
        return 0.0


def usage_by_module(
    fleets: Iterable[Mapping[str, Any]],
    known: Placements | None = None,
    measured: Measures | None = None,
) -> dict[tuple[str, str], Usage]:
    """(namespace, module) -> the fleets (by name, same namespace) placing it, per tier, and
    what each measured of it: the drift pass's measures (``measured``), else the fleet's
    ``status.measured``."""
    listed = list(fleets)
    out: dict[tuple[str, str], Usage] = {}
    for ns, fleet, entry in _placements(listed, known or {}):
        use = out.setdefault((ns, str(entry.get("module", ""))), Usage())
        use.fleets.add(fleet)
        use.tiers[str(entry.get("tier", ""))] += 1
        use.cpu += _cores(entry.get("cpu"))
    for ns, module, rate, cycles in _measures(listed, measured or {}):
        placed = out.get((ns, module))
        if placed is not None:  # a module its fleets no longer place shows no rate
            placed.measured.append((rate, cycles))
    return out


def _measures(
    fleets: Iterable[Mapping[str, Any]], known: Measures
) -> Iterable[tuple[str, str, float | None, float]]:
    for fleet in fleets:
        meta = fleet.get("metadata") or {}
        if meta.get("deletionTimestamp"):
            continue
        key = (meta.get("namespace") or "default", meta.get("name", ""))
        if key in known:
            for module, (rate, cycles) in known[key].items():
                yield key[0], module, rate, cycles
            continue
        for entry in (fleet.get("status") or {}).get("measured") or []:
            rate, cycles = entry.get("measuredMissRate"), entry.get("cycles")
            if isinstance(rate, int | float) and isinstance(cycles, int | float):
                yield key[0], str(entry.get("module", "")), float(rate), float(cycles)


def usage_by_node(
    fleets: Iterable[Mapping[str, Any]], known: Placements | None = None
) -> dict[str, Usage]:
    """Kubernetes Node name -> the fleets (``namespace/name``) placing instances on it."""
    out: dict[str, Usage] = {}
    for ns, fleet, entry in _placements(fleets, known or {}):
        use = out.setdefault(str(entry.get("node", "")), Usage())
        use.fleets.add(f"{ns}/{fleet}")
        use.tiers[str(entry.get("tier", ""))] += 1
        use.cpu += _cores(entry.get("cpu"))
    return out


def _offloadable(module: Mapping[str, Any]) -> str | None:
    try:
        return classify(Taxonomy.model_validate((module.get("spec") or {}).get("taxonomy"))).value
    except ValidationError:
        return None  # the fleet's reconcile reports the invalid spec, naming the field


def module_status(module: Mapping[str, Any], usage: Usage | None) -> Obj:
    """The part of a SoftwareModule's status this pass owns."""
    use = usage or Usage()
    rate, shown = miss_fields(pooled_miss_rate(use.measured))
    status = SoftwareModuleStatus(
        observed_generation=(module.get("metadata") or {}).get("generation"),
        offloadable=_offloadable(module),
        fleets=sorted(use.fleets),
        instances=use.instances,
        split=split_text(use.tiers),
        measured_miss_rate=rate,
        measured_miss=shown,
    )
    return wire(status)


def compute_node_status(
    compute_node: Mapping[str, Any],
    usage: Usage | None,
    node: Mapping[str, Any] | None,
    others: Held | None = None,
) -> Obj:
    """The status of a ComputeNode: its Node's readiness and allocatable, who uses it, what
    pods fogfleet does not own request there (``others``) and what is left."""
    use = usage or Usage()
    other_cpu = others.cpu if others is not None else 0.0
    meta = compute_node.get("metadata") or {}
    generation = meta.get("generation")
    name = (compute_node.get("spec") or {}).get("nodeName") or meta.get("name", "")
    health = node_health(node)
    alloc = ((node or {}).get("status") or {}).get("allocatable") or {}
    cluster = (compute_node.get("spec") or {}).get("managedCluster")
    if node is None:
        ready = condition("Ready", False, "NodeNotFound", f"No Kubernetes Node {name}", generation)
    elif cluster:
        what = f"ManagedCluster {cluster} (through the OCM hub)"
        ready = (
            condition("Ready", False, "ClusterUnavailable", f"{what} is {health}", generation)
            if health
            else condition("Ready", True, "ClusterAvailable", f"{what} can run pods", generation)
        )
    elif health:
        ready = condition("Ready", False, "NodeUnavailable", f"Node {name} is {health}", generation)
    else:
        ready = condition("Ready", True, "NodeReady", f"Node {name} can run pods", generation)
    conditions = merge_conditions(written_status(compute_node).get("conditions"), [ready])
    status = ComputeNodeStatus(
        observed_generation=generation,
        conditions=conditions,
        ready=not health,
        allocatable_cpu=str(alloc.get("cpu", "")),
        allocatable_memory=str(alloc.get("memory", "")),
        fleets=sorted(use.fleets),
        instances=use.instances,
        cpu_planned=format_cores(use.cpu),
        cpu_others=format_cores(other_cpu),
        cpu_free=_free(alloc.get("cpu"), use.cpu + other_cpu),
    )
    return wire(status)


def _free(allocatable: Any, taken: float) -> str | None:
    """Allocatable CPU less what is taken ("" when the Node says nothing)."""
    if allocatable in (None, ""):
        return None
    try:
        return format_cores(max(parse_cpu(allocatable) - taken, 0.0))
    except ValueError:
        return None


def _differs(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Some key this pass owns changed (other writers' keys, and stamps alone, do not count)."""
    for key, value in new.items():
        if key == "conditions":
            if without_transition_times(old.get(key)) != without_transition_times(value):
                return True
        elif old.get(key) != value:
            return True
    return False


def reconcile_usage(deps: Deps) -> int:
    """Bring every SoftwareModule's and ComputeNode's usage status up to date; return the
    number of objects patched (0 when nothing changed: the pass is idempotent)."""
    kube = deps.kube
    fleets = kube.list_fleets(None)
    patched = 0
    # a snapshot: fleet reconciles replace entries meanwhile
    states = deps.store.states()
    known = {s.key: s.placement for s in states if s.placement is not None}
    measured = {
        s.key: {m: (d.measured, d.cycles) for m, d in s.drift.modules.items()}
        for s in states
        if s.drift.modules is not None
    }
    by_module = usage_by_module(fleets, known, measured)
    for module in kube.list_modules(None):
        meta = module.get("metadata") or {}
        ns, name = meta.get("namespace") or "default", meta.get("name", "")
        status = module_status(module, by_module.get((ns, name)))
        if status["offloadable"] is None:
            del status["offloadable"]
        if _differs(written_status(module), status):
            kube.patch_module_status(ns, name, status)
            patched += 1
    by_node = usage_by_node(fleets, known)
    compute_nodes = kube.list_compute_nodes()
    # a ComputeNode that stands for a managed cluster: its Node is what the OCM hub says
    listed = [*kube.list_nodes(), *hub_nodes(deps, compute_nodes)[0]]
    nodes = {(n.get("metadata") or {}).get("name", ""): n for n in listed}
    _, others = pod_requests(kube.list_node_load())
    for cn in compute_nodes:
        meta = cn.get("metadata") or {}
        node_name = (cn.get("spec") or {}).get("nodeName") or meta.get("name", "")
        status = compute_node_status(
            cn, by_node.get(node_name), nodes.get(node_name), others.get(node_name)
        )
        if _differs(written_status(cn), status):
            kube.patch_compute_node_status(meta.get("name", ""), status)
            patched += 1
    if patched:
        log.info("Updated the usage status of %d SoftwareModules/ComputeNodes", patched)
    return patched
