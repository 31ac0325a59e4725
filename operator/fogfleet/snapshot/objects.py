"""Pure readers of the objects as the API server (or a folder) gives them: dicts in, typed
facts out. The one place that reads a Node's health, a Deployment's bound node, and the
SoftwareModules' status (the autoscaler's pools, the profile corrections, the observed miss
rates): the operator, the CLI and the kubectl plugin all read them here."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.api.labels import ANNOTATION_NODE
from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.base import status_part
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import ScalingStatus
from fogfleet.domain.rows import Learnt
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import identity_of

__all__ = [
    "Placement",
    "bound_nodes",
    "current_placement",
    "fleet_key",
    "measured_rates",
    "node_health",
    "parse_fleet",
    "profile_corrections",
    "profiled",
    "profiling_record",
    "recorded_corrections",
    "scaling_pools",
    "scaling_status",
    "written_status",
]

Obj = dict[str, Any]
Placement = dict[tuple[str, str, int], str]  # (robot, module, replica) -> node


def fleet_key(body: Mapping[str, Any]) -> tuple[str, str]:
    """(namespace, name) of a RobotFleet as the API server sends it."""
    meta = body.get("metadata") or {}
    return meta.get("namespace") or "default", meta["name"]


def parse_fleet(body: Mapping[str, Any]) -> RobotFleet:
    """The fleet's spec as its model (InvalidSpec names the field)."""
    parsed = parse_object({k: v for k, v in body.items() if k != "status"})
    if not isinstance(parsed, RobotFleet):
        raise InvalidSpec(f"RobotFleet/{fleet_key(body)[1]}", "kind", "not a RobotFleet")
    return parsed


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


def bound_nodes(dep: Mapping[str, Any]) -> list[str]:
    """The node names of a Deployment's required node affinity; of its metadata alone (a
    metadata-only list), the node its ``fogfleet.io/node`` annotation names."""
    if "spec" not in dep:
        node = ((dep.get("metadata") or {}).get("annotations") or {}).get(ANNOTATION_NODE)
        return [str(node)] if node else []
    try:
        terms = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        values: list[str] = list(terms[0]["matchExpressions"][0]["values"])
    except (KeyError, IndexError, TypeError):
        return []
    return values


def current_placement(deployments: Iterable[Obj]) -> Placement:
    """(robot, module, replica) -> the one node its Deployment is bound to."""
    out: Placement = {}
    for dep in deployments:
        ident = identity_of(dep)
        if ident is None or (dep.get("metadata") or {}).get("deletionTimestamp"):
            continue
        values = bound_nodes(dep)
        if len(values) == 1:
            out[ident] = values[0]
    return out


def scaling_status(module: Mapping[str, Any]) -> ScalingStatus | None:
    """The autoscaler's last decision on a SoftwareModule (``status.scaling``); None when there
    is none or it is not in the shape we write."""
    return status_part(module, "scaling", ScalingStatus)


def scaling_pools(modules: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """The autoscaler's last decision per shared module: {module: {tier: replicas}}.

    Read from the SoftwareModules as the API server sends them (one namespace's): the
    catalog's modules are parsed without their status, so they never carry
    ``status.scaling``. A status this operator did not write in this shape is ignored."""
    pools: dict[str, dict[str, int]] = {}
    for raw in modules:
        scaling = scaling_status(raw)
        if scaling is not None:
            tiers = {p.tier: p.replicas for p in scaling.pools}
            pools[str(raw["metadata"]["name"])] = tiers or {"any": scaling.desired_replicas}
    return pools


def profile_corrections(modules: Iterable[Mapping[str, Any]]) -> dict[tuple[str, str], Learnt]:
    """(module, hardware type) -> its correction, from the SoftwareModules'
    status.profileCorrection (as the API server sends them); malformed entries are ignored."""
    out: dict[tuple[str, str], Learnt] = {}
    for raw in modules:
        name = str((raw.get("metadata") or {}).get("name", ""))
        for entry in (raw.get("status") or {}).get("profileCorrection") or []:
            try:
                factor = float(entry["factor"])
                noise = float(entry.get("noiseMillis", 0.0)) / 1e3
                cycles = float(entry.get("noiseCycles", 0.0))
                hw = str(entry["hardwareType"])
            except (AttributeError, KeyError, TypeError, ValueError):
                continue
            if factor > 0 and noise >= 0 and cycles >= 0 and hw:
                out[(name, hw)] = Learnt(factor, noise, cycles)
    return out


def written_status(obj: Mapping[str, Any]) -> Obj:
    """An object's status as its writers last wrote it: what a status writer compares its new
    status with and sets its conditions into. Planning never reads it raw: it asks the typed
    readers of this module."""
    status = obj.get("status")
    return dict(status) if isinstance(status, Mapping) else {}


def recorded_corrections(module: Mapping[str, Any]) -> dict[Any, Obj]:
    """A SoftwareModule's status.profileCorrection entries as recorded, by hardware type (the
    closed loop rewrites the types it learns and keeps the others)."""
    entries = (module.get("status") or {}).get("profileCorrection") or []
    return {e.get("hardwareType"): dict(e) for e in entries if isinstance(e, Mapping)}


def profiling_record(module: Mapping[str, Any]) -> Any:
    """A SoftwareModule's status.profiling as recorded (None: never profiled)."""
    return (module.get("status") or {}).get("profiling")


def profiled(modules: Iterable[Mapping[str, Any]]) -> tuple[tuple[str, str], ...]:
    """What the modules' automatic profiling has recorded, per module (a new profile is a new
    planning input)."""
    return tuple(
        sorted(
            (str(m["metadata"]["name"]), repr((profiling_record(m) or {}).get("rows")))
            for m in modules
            if profiling_record(m)
        )
    )


def measured_rates(raw: Obj, raw_modules: Iterable[Obj]) -> dict[str, float]:
    """Each module's measured miss rate: the fleet's ``status.measured`` (its pods, over the
    drift window), else the cycle-weighted ``missedPercent`` of the SoftwareModule's
    ``status.observed`` rows (every fleet's pods of the module)."""
    out: dict[str, float] = {}
    for m in (raw.get("status") or {}).get("measured") or []:
        if m.get("measuredMissRate") is not None:
            out[str(m["module"])] = float(m["measuredMissRate"])
    for mod in raw_modules:
        name = str(mod["metadata"]["name"])
        rows = [
            r
            for r in (mod.get("status") or {}).get("observed") or []
            if r.get("cycles") and r.get("missedPercent") is not None
        ]
        cycles = sum(float(r["cycles"]) for r in rows)
        if name not in out and cycles > 0:
            missed = sum(float(r["cycles"]) * float(r["missedPercent"]) for r in rows)
            out[name] = missed / cycles / 100.0
    return out
