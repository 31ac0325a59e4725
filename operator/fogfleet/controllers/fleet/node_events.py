"""The Events of a fleet's nodes going away and coming back (a reboot, a crash, a cordon).

A node the fleet plans on that turns unavailable (NotReady, cordoned, deleted) gets one Warning
``NodeUnavailable`` naming the node, why, and the fleet's modules that ran there: which of them
wait for it (no other node allowed: they stay bound to it) and which are planned elsewhere. Its
return gets one Normal ``NodeAvailable``. Without them a user saw only ``Ready=False`` and pods
restarting, not which machine failed.

The nodes seen unavailable are a cache (``FleetState.unavailable``): an operator that restarts
while a node is down reports it once more; one that restarts while a node comes back says
nothing of its return (the Ready condition does).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

from fogfleet.domain.problem import Problem

__all__ = ["hosted_modules", "node_events"]

Event = tuple[str, str, str]
LISTED = 10  # modules named in one message


def hosted_modules(
    problem: Problem, current: Mapping[tuple[str, str, int], str]
) -> dict[str, list[str]]:
    """Kubernetes Node -> the instances of the fleet bound to it (``robot/module``), from the
    placement its Deployments had before this pass."""
    out: dict[str, list[str]] = {}
    for i, inst in enumerate(problem.instances):
        node = current.get((inst.robot, inst.module, inst.replica))
        if node is not None:
            out.setdefault(node, []).append(problem.label(i))
    return {node: sorted(labels) for node, labels in out.items()}


def _names(labels: list[str]) -> str:
    more = f" and {len(labels) - LISTED} more" if len(labels) > LISTED else ""
    return ", ".join(labels[:LISTED]) + more


def node_events(
    before: Mapping[str, str],
    now: Mapping[str, str],
    hosted: Mapping[str, list[str]],
    waiting: Collection[str],
) -> list[Event]:
    """Events for the change from ``before`` to ``now`` (Kubernetes Node -> why it is
    unavailable); ``hosted``: the fleet's instances per Node; ``waiting``: the instances left
    bound to an unavailable node (no other node allowed)."""
    events: list[Event] = []
    for node in sorted(set(now) - set(before)):
        mods = hosted.get(node, [])
        if not mods:
            what = "no module of the fleet ran there"
        else:
            stay = [m for m in mods if m in waiting]
            move = [m for m in mods if m not in waiting]
            parts = [f"{len(mods)} module(s) ran there: {_names(mods)}"]
            if stay:
                parts.append(f"{len(stay)} wait for it (no other node allowed)")
            if move:
                parts.append(f"{len(move)} planned on other nodes")
            what = "; ".join(parts)
        events.append(("Warning", "NodeUnavailable", f"Node {node} is {now[node]}: {what}"))
    for node in sorted(set(before) - set(now)):
        mods = hosted.get(node, [])
        what = f": {len(mods)} module(s) bound to it: {_names(mods)}" if mods else ""
        events.append(("Normal", "NodeAvailable", f"Node {node} is available again{what}"))
    return events
