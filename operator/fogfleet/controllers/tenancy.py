"""What other tenants hold on each node, as one fleet plans (``domain.tenancy``).

Read from the pods on every node (``KubePort.list_node_load``, from the watch caches) and the
other fleets' claims in the store (their plans, recorded when they are made). Another fleet
holds the larger of what its plan claims and what its pods request on a node (a plan not
rolled out yet holds its room already; pods of a fleet without a plan, k8s-default, hold
what they request). A pod fogfleet does not own holds what it requests.

Planning is serialised (``Deps.planning``): a fleet plans into what the others claimed, and
records its own claims before the next one plans, so two fleets applied at the same moment
never plan the same room twice.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.api.labels import LABEL_FLEET, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.names import label_value
from fogfleet.domain.tenancy import Held

from .state import FleetKey, FleetStore

__all__ = ["claims_in", "held_by_others", "held_signature", "pod_requests"]

Obj = dict[str, Any]
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


def claims_in(store: FleetStore) -> dict[FleetKey, Claims]:
    """Every fleet's claims, as recorded with its plan."""
    return {s.key: s.claims for s in store.states() if s.claims}


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
