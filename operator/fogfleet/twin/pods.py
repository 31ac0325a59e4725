"""From the cluster's pods to each shared service's replicas per tier (pure).

A replica counts when its pod (label ``app.kubernetes.io/managed-by=fogfleet``, with
``fogfleet.io/module``) is Running, Ready and not terminating. Its tier is the pod's
``fogfleet.io/tier`` label, else the ``fogfleet.io/tier`` label of the node it is bound to
(``spec.nodeName``). It is *starting* until the pool's setup time has passed since it became
Ready (kwok marks pods Running at once; the setup time is what a real detector needs to load
its model), then *ready*.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fogfleet.api.labels import LABEL_MODULE, LABEL_TIER
from fogfleet.api.timestamps import parse_timestamp

__all__ = ["ReplicaCount", "count_replicas", "ready_since"]

Obj = Mapping[str, Any]
ReplicaCount = dict[tuple[str, str], dict[str, tuple[int, int]]]  # (ns, module) -> tier -> (r, s)


def ready_since(pod: Obj) -> float | None:
    """When the pod became Ready (epoch seconds), or None if it is not serving."""
    meta = pod.get("metadata") or {}
    st = pod.get("status") or {}
    if meta.get("deletionTimestamp") or st.get("phase") != "Running":
        return None
    ready = next((c for c in st.get("conditions") or [] if c.get("type") == "Ready"), None)
    if ready is not None and ready.get("status") != "True":
        return None
    stamp = parse_timestamp((ready or {}).get("lastTransitionTime")) or parse_timestamp(
        st.get("startTime")
    )
    return stamp if stamp is not None else 0.0


def count_replicas(
    pods: Iterable[Obj],
    node_tiers: Mapping[str, str],
    setup_seconds: Mapping[tuple[str, str, str], float],
    now: float,
) -> ReplicaCount:
    """(ready, starting) per tier for every (namespace, module) that has running pods.

    ``setup_seconds`` maps (namespace, module, tier) to the pool's setup time (0 if absent)."""
    out: ReplicaCount = {}
    for pod in pods:
        meta = pod.get("metadata") or {}
        labels = meta.get("labels") or {}
        module = labels.get(LABEL_MODULE)
        since = ready_since(pod)
        if not module or since is None:
            continue
        node = (pod.get("spec") or {}).get("nodeName") or ""
        tier = labels.get(LABEL_TIER) or node_tiers.get(node, "")
        if not tier:
            continue
        ns = meta.get("namespace") or "default"
        setup = setup_seconds.get((ns, module, tier), 0.0)
        ready, starting = out.setdefault((ns, module), {}).get(tier, (0, 0))
        if now - since >= setup:
            ready += 1
        else:
            starting += 1
        out[(ns, module)][tier] = (ready, starting)
    return out
