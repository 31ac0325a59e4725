"""Where kube-scheduler's arms stand after the fleet is applied: every instance's pod bound
and Ready, or left Pending because no node has room for its request (the protocol's Pending
rule, ``protocol``). The planner arms wait for the fleet's Ready condition instead.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import all_pods, conditions

__all__ = ["instance_states", "wait_bound_or_pending"]

Key = tuple[str, str]  # (module, robot), as the workload's metrics name an instance
MODULE, ROBOT = "fogfleet.io/module", "fogfleet.io/robot"  # labels and annotations alike
COMPONENT = "app.kubernetes.io/component"  # set on standbys and profiling pods, not modules


def instance_states(pods: Iterable[dict[str, Any]]) -> dict[Key, str]:
    """Each module instance's state from its pods: ``Ready``, ``Unschedulable`` (Pending:
    kube-scheduler found no node with room) or ``Starting`` (anything else). A pod being
    deleted is left out; of two pods of one instance (a rollout) the best state counts."""
    rank = {"Starting": 0, "Unschedulable": 1, "Ready": 2}
    out: dict[Key, str] = {}
    for pod in pods:
        meta = pod.get("metadata") or {}
        labels = meta.get("labels") or {}
        if MODULE not in labels or meta.get("deletionTimestamp") or labels.get(COMPONENT):
            continue  # a discovery server, a standby, or a pod on its way out
        names = {**labels, **(meta.get("annotations") or {})}  # annotations: the exact names
        key = (str(names[MODULE]), str(names.get(ROBOT, "")))
        conds = conditions(pod)
        scheduled = conds.get("PodScheduled", {})
        if conds.get("Ready", {}).get("status") == "True":
            state = "Ready"
        elif scheduled.get("status") == "False" and scheduled.get("reason") == "Unschedulable":
            state = "Unschedulable"
        else:
            state = "Starting"
        if key not in out or rank[state] > rank[out[key]]:
            out[key] = state
    return out


def wait_bound_or_pending(kube: Kube, namespace: str, instances: int, timeout: float) -> set[Key]:
    """Until every one of the ``instances`` is Ready or Unschedulable; the Unschedulable ones."""
    seen: dict[Key, str] = {}

    def settled() -> bool:
        seen.clear()
        seen.update(instance_states(all_pods(kube, namespace)))
        return len(seen) >= instances and "Starting" not in seen.values()

    kube.wait_for(
        f"all {instances} instances of {namespace} Ready or Unschedulable", settled, timeout, 1
    )
    return {key for key, state in seen.items() if state == "Unschedulable"}
