"""Turn what the API server holds into a fleet's planning inputs (pure: dicts in, models out).

- ComputeNodes without ``spec.capacity`` take the Kubernetes Node's allocatable.
- A ComputeNode whose Node is missing, NotReady or cordoned is *unavailable*: it stays in the
  problem (so references resolve) but leaves every gene space.
- The current placement comes from the fleet's Deployments (their single required node).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.computenode import ComputeNode, NodeResources
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.profiling import with_profiled
from fogfleet.domain.tenancy import Held, with_held
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import identity_of

__all__ = ["Inputs", "current_placement", "gather", "node_health"]

Obj = dict[str, Any]


@dataclass
class Inputs:
    catalog: Catalog
    unavailable: dict[str, str]  # ComputeNode name -> why ("NotReady", "missing", ...)
    broken: dict[str, InvalidSpec] = field(default_factory=dict)  # "Kind/name" -> parse error


def node_health(node: Mapping[str, Any] | None) -> str:
    """ "" when the Node can run pods, else a short reason."""
    if node is None:
        return "missing (no Kubernetes Node of that name)"
    if (node.get("spec") or {}).get("unschedulable"):
        return "cordoned"
    conds = {c.get("type"): c for c in (node.get("status") or {}).get("conditions") or []}
    ready = conds.get("Ready")
    if ready is None:
        return "not reporting Ready yet"
    if ready.get("status") != "True":
        return f"NotReady ({ready.get('reason') or ready.get('status')})"
    return ""


def _with_capacity(cn: ComputeNode, node: Mapping[str, Any] | None) -> ComputeNode:
    if cn.spec.capacity is not None:
        return cn
    alloc = ((node or {}).get("status") or {}).get("allocatable") or {}
    gpu = int(str(alloc.get("nvidia.com/gpu", "0")) or 0)
    cap = NodeResources(cpu=alloc.get("cpu", "1m"), memory=alloc.get("memory", 0), gpu=gpu)
    return cn.model_copy(update={"spec": cn.spec.model_copy(update={"capacity": cap})})


def gather(
    fleet: RobotFleet,
    compute_nodes: Iterable[Obj],
    modules: Iterable[Obj],
    nodes: Iterable[Obj],
    held: Mapping[str, Held] | None = None,
) -> Inputs:
    """Parse the CRs (remembering broken ones) and attach Node capacity and health; ``held``:
    what other tenants hold on each Node, which the fleet plans around."""
    by_node = {(n.get("metadata") or {}).get("name"): n for n in nodes}
    catalog = Catalog()
    broken: dict[str, InvalidSpec] = {}
    unavailable: dict[str, str] = {}
    for raw in compute_nodes:
        name = (raw.get("metadata") or {}).get("name", "?")
        try:
            cn = parse_object(_clean(raw))
        except InvalidSpec as exc:
            broken[f"ComputeNode/{name}"] = exc
            continue
        assert isinstance(cn, ComputeNode)
        node = by_node.get(cn.node_name)
        why = node_health(node)
        if why:
            unavailable[cn.metadata.name] = why
        try:
            catalog.add(with_held(_with_capacity(cn, node), (held or {}).get(cn.node_name)))
        except ValueError as exc:
            broken[f"ComputeNode/{name}"] = InvalidSpec(
                f"ComputeNode/{name}", "status.allocatable", str(exc)
            )
    for raw in modules:
        name = (raw.get("metadata") or {}).get("name", "?")
        try:
            mod = parse_object(_clean(raw))
        except InvalidSpec as exc:
            broken[f"SoftwareModule/{name}"] = exc
            continue
        assert isinstance(mod, SoftwareModule)
        catalog.add(with_profiled(mod, raw))
    return Inputs(catalog, unavailable, broken)


def _clean(raw: Mapping[str, Any]) -> Obj:
    """The object without status (the models' status is ours; others may write their own)."""
    return {k: v for k, v in raw.items() if k != "status"}


def current_placement(deployments: Iterable[Obj]) -> dict[tuple[str, str, int], str]:
    """(robot, module, replica) -> the one node its Deployment is bound to."""
    out: dict[tuple[str, str, int], str] = {}
    for dep in deployments:
        ident = identity_of(dep)
        if ident is None or (dep.get("metadata") or {}).get("deletionTimestamp"):
            continue
        values = bound_nodes(dep)
        if len(values) == 1:
            out[ident] = values[0]
    return out


def bound_nodes(dep: Mapping[str, Any]) -> list[str]:
    """The node names of a Deployment's required node affinity."""
    try:
        terms = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        values: list[str] = list(terms[0]["matchExpressions"][0]["values"])
    except (KeyError, IndexError, TypeError):
        return []
    return values
