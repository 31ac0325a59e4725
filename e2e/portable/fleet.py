"""The portable fleet: four ROS 2 modules per robot that the workload image plays, sized to the
nodes ``nodes.pick`` found, so its messages cross nodes in both directions:

    sensor (robot) -scan-> detector (edge/cloud preferred, standby on board) -objects-> safety
                   \\-scan-> planner (edge/cloud required) ---------------------plan-> (robot)

Each robot's modules talk only among themselves (the operator gives each robot a discovery
server); the workloads count any message of another robot (``fogfleet_foreign_messages_total``).
Profile rows name the nodes' own hardware types, so any cluster's labels fit.
"""

from __future__ import annotations

from typing import Any

from e2e.portable.nodes import Topology

__all__ = [
    "DETECTOR", "FLEET", "MODULES", "PLANNER", "SAFETY", "SENSOR", "fleet_objects", "module_object",
]  # fmt: skip

FLEET = "portable"
SENSOR, DETECTOR, PLANNER, SAFETY = "sensor", "detector", "planner", "safety"
MODULES = (SENSOR, DETECTOR, PLANNER, SAFETY)
SILENT_CYCLES = 3
METRICS_PORT = 9100


def _topics(items: list[tuple[str, int, int]]) -> list[dict[str, Any]]:
    return [{"name": n, "sizeBytes": s, "rateHz": r} for n, s, r in items]


def module_object(
    name: str,
    namespace: str,
    image: str,
    pull_policy: str,
    *,
    cycle_ms: int,
    taxonomy: tuple[str, str, str],
    subscribes: list[tuple[str, int, int]],
    publishes: list[tuple[str, int, int]],
    rows: list[tuple[str | list[str], str | float, float, float]],
    memory: str = "192Mi",
    **extra: Any,
) -> dict[str, Any]:
    """A SoftwareModule the workload image plays (the e2e suite's one module builder).

    ``rows`` are profile rows (hardware type or types, CPU, mean ms, std ms); ``extra`` goes
    into the spec as it is."""
    spec: dict[str, Any] = {
        "template": {"image": image, "metricsPort": METRICS_PORT, "imagePullPolicy": pull_policy},
        "taxonomy": dict(zip(("executionPattern", "realtime", "safety"), taxonomy, strict=True)),
        "cycleTimeMillis": cycle_ms,
        "activationPercent": 100,
        "resources": {"cpu": "100m", "memory": memory},
        "topics": {"subscribes": _topics(subscribes), "publishes": _topics(publishes)},
        "profile": [
            # plain numbers (type: number), fractions unquoted
            {"hardwareType": hw, "cpu": cpu, "meanMillis": mean, "stdMillis": std}
            for hardware, cpu, mean, std in rows
            for hw in ([hardware] if isinstance(hardware, str) else hardware)
        ],
        **extra,
    }
    return {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "SoftwareModule",
        "metadata": {"name": name, "namespace": namespace},
        "spec": spec,
    }


def fleet_objects(
    topology: Topology, namespace: str, image: str, pull_policy: str
) -> list[dict[str, Any]]:
    """The SoftwareModules and the RobotFleet (ComputeNodes come from ``nodes.compute_nodes``)."""
    robot_hw = topology.hardware_of("robot")
    off_hw = sorted({topology.hardware[n] for n in topology.offload})
    off_tiers = sorted({topology.tier[n] for n in topology.offload})
    scan, objects, plan = ("scan", 4096, 10), ("objects", 512, 10), ("plan", 2048, 1)
    args = (namespace, image, pull_policy)
    modules = [
        module_object(SENSOR, *args, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                subscribes=[], publishes=[scan], rows=[(robot_hw, "50m", 4, 0.5)]),
        # offloaded when it can be; its standby on the robot takes over when it falls silent
        module_object(DETECTOR, *args, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                subscribes=[scan], publishes=[objects],
                rows=[(robot_hw, "100m", 30, 3), (off_hw, "100m", 15, 1.5)],
                preferredTiers=off_tiers,
                fallback={"mode": "onboard", "silentCycles": SILENT_CYCLES,
                          "stepBackCycles": 10}),
        # never on a robot
        module_object(PLANNER, *args, cycle_ms=1000, taxonomy=("periodic", "soft", "relevant"),
                subscribes=[scan], publishes=[plan], rows=[(off_hw, "100m", 120, 10)],
                requirements={"tiers": off_tiers}),
        module_object(SAFETY, *args, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                subscribes=[objects, plan], publishes=[("stop", 64, 10)],
                rows=[(robot_hw, "50m", 3, 0.3)]),
    ]  # fmt: skip
    fleet = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "RobotFleet",
        "metadata": {"name": FLEET, "namespace": namespace},
        "spec": {
            "robots": list(topology.robots),
            "nodes": list(topology.offload),
            "modules": [{"name": name} for name in MODULES],
            "scheduler": {"population": 20, "generations": 10, "seed": 1},
        },
    }
    return [*modules, fleet]
