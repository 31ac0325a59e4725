"""Room held by others: what the other tenants of a site hold on each Node, as one fleet plans,
and how a refusal or a degradation names them in amounts a user can act on.

Read from the pods on every node (their requests) and the other fleets' claims (their plans).
Another fleet holds the larger of what its plan claims and what its pods request on a node (a
plan not rolled out yet holds its room already; pods of a fleet without a plan, k8s-default,
hold what they request). A pod fogfleet does not own holds what it requests.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from fogfleet.api.labels import LABEL_FLEET, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.api.v1alpha1.placement import placement_entries_of
from fogfleet.domain.problem import Problem
from fogfleet.domain.tenancy import Held

__all__ = [
    "Claims",
    "FleetKey",
    "held_by_others",
    "held_signature",
    "pod_requests",
    "room_note",
    "status_claims",
]

FleetKey = tuple[str, str]  # (namespace, name)
Claims = Mapping[str, tuple[float, float]]  # node -> (cpu, memory) a plan requests there


def pod_requests(
    loads: Iterable[Mapping[str, Any]],
) -> tuple[dict[tuple[FleetKey, str], tuple[float, float]], dict[str, Held]]:
    """The pods' requests per (fleet, node) for fogfleet's pods, and per node for the rest."""
    fleets: dict[tuple[FleetKey, str], tuple[float, float]] = {}
    others: dict[str, Held] = {}
    for load in loads:
        meta = load.get("metadata") or {}
        node = str((load.get("spec") or {}).get("nodeName") or "")
        req = load.get("requests") or {}
        cpu, mem = float(req.get("cpu", 0.0)), float(req.get("memory", 0.0))
        labels = meta.get("labels") or {}
        ns = str(meta.get("namespace") or "default")
        fleet = labels.get(LABEL_FLEET)
        if fleet and labels.get(LABEL_MANAGED_BY) == MANAGER:
            key = ((ns, str(fleet)), node)
            c, m = fleets.get(key, (0.0, 0.0))
            fleets[key] = (c + cpu, m + mem)
        elif cpu or mem:
            others[node] = others.get(node, Held()).plus(cpu, mem, f"pods in {ns}")
    return fleets, others


def held_by_others(
    me: FleetKey, loads: Iterable[Mapping[str, Any]], claims: Mapping[FleetKey, Claims]
) -> dict[str, Held]:
    """Node -> what every tenant but fleet ``me`` holds there."""
    running, held = pod_requests(loads)  # keyed by the pods' fleet label
    labelled = {(ns, label_value(name)): (ns, name) for ns, name in claims}  # long names: hashed
    names = {k for k, _ in running} | set(labelled)
    mine = (me[0], label_value(me[1]))
    for label in sorted(names - {mine}):
        fleet = labelled.get(label, label)
        planned = claims.get(fleet, {})
        nodes = set(planned) | {n for (f, n) in running if f == label}
        for node in sorted(nodes):
            c_plan, m_plan = planned.get(node, (0.0, 0.0))
            c_run, m_run = running.get((label, node), (0.0, 0.0))
            cpu, mem = max(c_plan, c_run), max(m_plan, m_run)
            if cpu or mem:
                held[node] = held.get(node, Held()).plus(
                    cpu, mem, f"RobotFleet {fleet[0]}/{fleet[1]}"
                )
    return held


def held_signature(held: Mapping[str, Held], nodes: Iterable[str] | None) -> tuple[Any, ...]:
    """What others hold on the fleet's nodes, to the millicore and the MiB (the stamp: a
    change re-checks the fleet's plan)."""
    wanted = set(nodes) if nodes is not None else set(held)
    return tuple(
        sorted(
            (n, round(h.cpu * 1000), round(h.memory / 2**20))
            for n, h in held.items()
            if n in wanted
        )
    )


def _cores(value: float) -> str:
    return f"{round(value, 3):g}"


def room_note(problem: Problem, held: Mapping[str, Held]) -> str:
    """``problem``, planned into the room ``held`` leaves: what the
    fleet needs at its deadlines' CPU against what its nodes have and what they leave it, then
    each shared node with who holds how much. "" when nobody else holds room on its nodes."""
    shared = [
        (j, held[nd.node_name])
        for j, nd in enumerate(problem.nodes)
        if nd.node_name in held and held[nd.node_name].cpu > 0
    ]
    if not shared:
        return ""
    left = problem.capacity[:, 0]
    taken = sum(h.cpu for _, h in shared)
    need = _needed_cores(problem)
    nodes = "; ".join(
        f"{problem.nodes[j].name} has {_cores(float(left[j]))} of "
        f"{_cores(float(left[j]) + h.cpu)} cores left ({h.itemised()})"
        for j, h in shared
    )
    return (
        f"other fleets and pods hold {_cores(taken)} cores on this fleet's nodes: it needs "
        f"{_cores(need)} cores at its deadlines' CPU where its nodes leave it "
        f"{_cores(float(left.sum()))} (of {_cores(float(left.sum()) + taken)}): {nodes}"
    )


def _needed_cores(problem: Problem) -> float:
    """The CPU the fleet's instances request at their deadlines' amounts (a degraded problem's
    ladder keeps them in its first rung), each on the node it may use that asks the least."""
    cpu = problem.limits.cpu_request
    ladder = problem.ladder if problem.levels is not None else None  # built only when degraded
    if ladder is not None:
        cpu = ladder.cpu[:, :, 0]
    masked = np.where(problem.allowed, cpu, np.inf)
    least = masked.min(axis=1) if masked.size else np.zeros(0)
    return float(least[np.isfinite(least)].sum())


def status_claims(fleets: Iterable[Mapping[str, Any]]) -> dict[FleetKey, Claims]:
    """Every fleet's claims as its status lists them (``status.placement``, or its compact
    form above the list's limit: node and CPU per instance): what a reader outside the operator
    knows of the plans (the operator keeps them in its store). A fleet whose status lists no
    placement yet claims nothing here: its pods' requests stand in."""
    out: dict[FleetKey, Claims] = {}
    for raw in fleets:
        meta = raw.get("metadata") or {}
        key = (str(meta.get("namespace") or "default"), str(meta.get("name") or ""))
        nodes: dict[str, tuple[float, float]] = {}
        for entry in placement_entries_of(raw.get("status") or {}):
            node, cpu = entry.get("node"), entry.get("cpu")
            if node and cpu is not None:
                held = nodes.get(str(node), (0.0, 0.0))[0]
                nodes[str(node)] = (held + parse_cpu(cpu), 0.0)
        if nodes:
            out[key] = nodes
    return out
