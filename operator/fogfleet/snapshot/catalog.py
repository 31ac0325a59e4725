"""The planning catalog of listed objects (pure: dicts in, models out).

- ComputeNodes without ``spec.capacity`` take the Kubernetes Node's allocatable.
- A ComputeNode whose Node is missing, NotReady or cordoned is *unavailable*: it stays in the
  catalog (so references resolve) but leaves every gene space (``problem_of``).
- A ComputeNode's capacity is less what other tenants hold on its Node (``domain.tenancy``).
- A SoftwareModule carries the rows its automatic profiling found (its status).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.v1alpha1.computenode import ComputeNode, NodeResources
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.profiling import with_profiled
from fogfleet.domain.tenancy import Held, with_held
from fogfleet.errors import InvalidSpec

from .clusters import with_claims
from .objects import node_health

__all__ = ["Inputs", "gather"]

Obj = dict[str, Any]


@dataclass
class Inputs:
    catalog: Catalog
    unavailable: dict[str, str]  # ComputeNode name -> why ("NotReady", "missing", ...)
    broken: dict[str, InvalidSpec] = field(default_factory=dict)  # "Kind/name" -> parse error


def _with_capacity(cn: ComputeNode, node: Mapping[str, Any] | None) -> ComputeNode:
    if cn.spec.capacity is not None:
        return cn
    alloc = ((node or {}).get("status") or {}).get("allocatable") or {}
    gpu = int(str(alloc.get("nvidia.com/gpu", "0")) or 0)
    cap = NodeResources(cpu=alloc.get("cpu", "1m"), memory=alloc.get("memory", 0), gpu=gpu)
    return cn.model_copy(update={"spec": cn.spec.model_copy(update={"capacity": cap})})


def gather(
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
        cn = _parsed(raw, ComputeNode, broken)
        if cn is None:
            continue
        node = by_node.get(cn.node_name)
        cn = with_claims(cn, node)  # a managed cluster's claims fill what it leaves out
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
        mod = _parsed(raw, SoftwareModule, broken)
        if mod is not None:
            catalog.add(with_profiled(mod, raw))
    return Inputs(catalog, unavailable, broken)


_Model = TypeVar("_Model", ComputeNode, SoftwareModule)


def _parsed(
    raw: Mapping[str, Any], kind: type[_Model], broken: dict[str, InvalidSpec]
) -> _Model | None:
    """The object as its model, or None with its error kept in ``broken`` as KIND/NAME."""
    try:
        obj = parse_object(_clean(raw))
    except InvalidSpec as exc:
        broken[f"{kind.__name__}/{(raw.get('metadata') or {}).get('name', '?')}"] = exc
        return None
    assert isinstance(obj, kind)
    return obj


def _clean(raw: Mapping[str, Any]) -> Obj:
    """The object without status (the models' status is ours; others may write their own)."""
    return {k: v for k, v in raw.items() if k != "status"}
