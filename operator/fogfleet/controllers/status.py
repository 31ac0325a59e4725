"""Build a RobotFleet's status (Kubernetes API conventions): conditions keyed by type with
CamelCase reasons and messages a person can act on, the placement table, objective values.

Pure functions of the plan and of what the cluster shows (Deployments and their pods).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

from fogfleet.render.deployments import ANNOTATION_SPEC_HASH, LABEL_INSTANCE

__all__ = ["Rollout", "condition", "finite", "merge_conditions", "now", "rollout", "same_status"]

Obj = dict[str, Any]


def now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def condition(
    type_: str, ok: bool | None, reason: str, message: str, generation: int | None
) -> Obj:
    status = "Unknown" if ok is None else ("True" if ok else "False")
    return {
        "type": type_,
        "status": status,
        "reason": reason,
        "message": message[:2000],
        "observedGeneration": generation,
    }


def merge_conditions(old: Iterable[Mapping[str, Any]], new: Sequence[Obj]) -> list[Obj]:
    """Keep lastTransitionTime where a condition's status did not change."""
    before = {c.get("type"): c for c in old}
    out = []
    for c in new:
        prev = before.get(c["type"])
        stamp = (
            prev.get("lastTransitionTime") if prev and prev.get("status") == c["status"] else None
        )
        out.append({**c, "lastTransitionTime": stamp or now()})
    return out


def same_status(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Equal apart from timestamps (so an idle reconcile patches nothing)."""

    def strip(s: Mapping[str, Any]) -> Any:
        out = {k: v for k, v in s.items() if k != "lastPlanTime" and v is not None}
        out["conditions"] = [
            {k: v for k, v in c.items() if k != "lastTransitionTime"}
            for c in s.get("conditions") or []
        ]
        return out

    return bool(strip(old) == strip(new))


class Rollout:
    """Where each desired Deployment stands, from the Deployments and pods the cluster shows."""

    def __init__(self) -> None:
        self.settled: list[str] = []  # running where planned
        self.waiting: list[str] = []  # not yet running anywhere
        self.moving: list[str] = []  # still running elsewhere; its new pod is on the way
        self.bound: dict[str, str] = {}  # Deployment name -> node of its running pod


def _pod_running(pod: Mapping[str, Any]) -> bool:
    st = pod.get("status") or {}
    if (pod.get("metadata") or {}).get("deletionTimestamp") or st.get("phase") != "Running":
        return False
    conds = {c.get("type"): c.get("status") for c in st.get("conditions") or []}
    return bool(conds.get("Ready", "True") == "True")


def affinity_nodes(dep: Mapping[str, Any]) -> list[str]:
    try:
        values: list[str] = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"]
        return values
    except (KeyError, IndexError, TypeError):
        return []


def _deployment_done(dep: Mapping[str, Any], want_hash: str | None) -> bool:
    meta = dep.get("metadata") or {}
    if want_hash and (meta.get("annotations") or {}).get(ANNOTATION_SPEC_HASH) != want_hash:
        return False
    st = dep.get("status") or {}
    replicas = (dep.get("spec") or {}).get("replicas", 1)
    return bool(
        st.get("observedGeneration", 0) >= meta.get("generation", 0)
        and st.get("updatedReplicas", 0) >= replicas
        and st.get("availableReplicas", 0) >= replicas
        and st.get("replicas", 0) <= replicas
    )


def rollout(desired: Sequence[Obj], deployments: Sequence[Obj], pods: Sequence[Obj]) -> Rollout:
    """Compare the desired Deployments with the cluster's Deployments and running pods."""
    by_name = {d["metadata"]["name"]: d for d in deployments}
    running: dict[str, list[str]] = {}
    for pod in pods:
        inst = ((pod.get("metadata") or {}).get("labels") or {}).get(LABEL_INSTANCE)
        node = (pod.get("spec") or {}).get("nodeName")
        if inst and node and _pod_running(pod):
            running.setdefault(inst, []).append(node)
    out = Rollout()
    for want in desired:
        name = want["metadata"]["name"]
        have = by_name.get(name)
        nodes = running.get(name, [])
        allowed = set(affinity_nodes(want))
        good = [n for n in nodes if n in allowed]
        if good:
            out.bound[name] = good[0]
        want_hash = (want["metadata"].get("annotations") or {}).get(ANNOTATION_SPEC_HASH)
        if (
            have is not None
            and _deployment_done(have, want_hash)
            and nodes
            and set(nodes) <= allowed
        ):
            out.settled.append(name)
        elif nodes and not set(nodes) <= allowed:
            out.moving.append(name)
        else:
            out.waiting.append(name)
    return out


def finite(x: float | None) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), 6)
