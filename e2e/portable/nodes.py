"""Which Nodes the portable suite may use, decided from the Nodes alone (their labels,
annotations, taints and Ready condition), and the ComputeNodes that declare them to fogfleet.

A Node is used when it is Ready, schedulable, carries no NoSchedule/NoExecute taint, is not a
kwok fake (annotation ``kwok.x-k8s.io/node``: it runs no containers) and has the two labels
docs/development.md asks for: ``fogfleet.io/tier`` (robot, edge or cloud) and
``fogfleet.io/hardware-type``. When some of those also carry ``fogfleet.io/e2e-real=true``,
only they are used (a way to keep the suite to some nodes), and the operator is pinned to them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "HARDWARE_LABEL",
    "REAL_LABEL",
    "TIER_LABEL",
    "NotEnoughNodes",
    "Topology",
    "compute_nodes",
    "pick",
]

TIER_LABEL = "fogfleet.io/tier"
HARDWARE_LABEL = "fogfleet.io/hardware-type"
REAL_LABEL = "fogfleet.io/e2e-real"
KWOK_ANNOTATION = "kwok.x-k8s.io/node"
TIERS = ("robot", "edge", "cloud")
ROBOTS_USED = 2  # two robots: enough to check that they never hear each other
WIFI = {"type": "wifi", "latencyMillis": 4, "jitterMillis": 1, "bandwidthMbps": 100}
LAN = {"type": "lan", "latencyMillis": 1, "jitterMillis": 0, "bandwidthMbps": 1000}


class NotEnoughNodes(Exception):
    """The cluster's labelled nodes cannot hold the portable fleet; the message says what lacks."""


@dataclass(frozen=True)
class Topology:
    robots: tuple[str, ...]
    offload: tuple[str, ...]
    """Edge and cloud nodes the fleet's offloaded modules may use."""
    tier: dict[str, str] = field(default_factory=dict)
    hardware: dict[str, str] = field(default_factory=dict)
    node_selector: dict[str, str] = field(default_factory=dict)
    """For the operator's pods: {REAL_LABEL: "true"} when the suite is kept to such nodes."""

    def hardware_of(self, tier: str) -> list[str]:
        return sorted({self.hardware[n] for n in (*self.robots, *self.offload)
                       if self.tier[n] == tier})  # fmt: skip


def _why_not(node: dict[str, Any]) -> str | None:
    meta, spec = node["metadata"], node.get("spec") or {}
    labels = meta.get("labels") or {}
    if KWOK_ANNOTATION in (meta.get("annotations") or {}):
        return "a kwok fake"
    if labels.get(TIER_LABEL) not in TIERS:
        return f"no {TIER_LABEL} label of {'/'.join(TIERS)}"
    if not labels.get(HARDWARE_LABEL):
        return f"no {HARDWARE_LABEL} label"
    conds = {c["type"]: c["status"] for c in (node.get("status") or {}).get("conditions") or []}
    if conds.get("Ready") != "True":
        return "not Ready"
    if spec.get("unschedulable"):
        return "cordoned"
    tainted = [t["key"] for t in spec.get("taints") or []
               if t.get("effect") in ("NoSchedule", "NoExecute")]  # fmt: skip
    if tainted:
        return f"tainted {', '.join(tainted)}"
    return None


def pick(nodes: Iterable[dict[str, Any]]) -> Topology:
    """The robots and offload nodes the suite uses, from ``kubectl get nodes -o json`` items."""
    usable: dict[str, dict[str, str]] = {}
    refused: list[str] = []
    for node in nodes:
        why = _why_not(node)
        if why is None:
            usable[node["metadata"]["name"]] = node["metadata"]["labels"]
        elif TIER_LABEL in (node["metadata"].get("labels") or {}):
            refused.append(f"{node['metadata']['name']} ({why})")
    selector: dict[str, str] = {}
    if any(labels.get(REAL_LABEL) == "true" for labels in usable.values()):
        usable = {n: labels for n, labels in usable.items() if labels.get(REAL_LABEL) == "true"}
        selector = {REAL_LABEL: "true"}
    tier = {n: labels[TIER_LABEL] for n, labels in usable.items()}
    robots = sorted(n for n, t in tier.items() if t == "robot")[:ROBOTS_USED]
    offload = sorted(n for n, t in tier.items() if t != "robot")
    if len(robots) < ROBOTS_USED or not offload:
        raise NotEnoughNodes(
            f"the portable suite needs {ROBOTS_USED} robot nodes and one edge or cloud node "
            f"(labels {TIER_LABEL} and {HARDWARE_LABEL}); usable: robots {robots}, edge/cloud "
            f"{offload}; not used: {', '.join(refused) or 'none'}"
        )
    return Topology(
        robots=tuple(robots),
        offload=tuple(offload),
        tier={n: tier[n] for n in (*robots, *offload)},
        hardware={n: usable[n][HARDWARE_LABEL] for n in (*robots, *offload)},
        node_selector=selector,
    )


def compute_nodes(topology: Topology) -> list[dict[str, Any]]:
    """One ComputeNode per used Node, named like it; capacity is read from the Node."""
    return [
        {
            "apiVersion": "fogfleet.io/v1alpha1",
            "kind": "ComputeNode",
            "metadata": {"name": name},
            "spec": {
                "tier": topology.tier[name],
                "hardwareType": topology.hardware[name],
                "network": [WIFI if topology.tier[name] == "robot" else LAN],
                "privacyLevel": 3,
            },
        }
        for name in (*topology.robots, *topology.offload)
    ]
