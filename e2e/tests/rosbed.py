"""Objects of a small ROS 2 fleet on the bed's real nodes (the workload image plays them), and
reading a pod's metrics: shared by the real-node e2e tests."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import Operator, install_crds, wait_ready
from e2e.portable.fleet import module_object
from e2e.portable.metrics import read

__all__ = [
    "EDGE",
    "IMAGE",
    "PROBE_PORT",
    "ROBOTS",
    "bed_objects",
    "compute_node",
    "operated_fleet",
    "ros_module",
    "scrape",
    "scrape_buckets",
    "scrape_series",
    "split_fleet",
]

ROBOTS = ("bed-robot-1", "bed-robot-2")
EDGE = "bed-edge-1"
IMAGE = "ghcr.io/fogfleet/ros2-module:0.1.0"
PROBE_PORT = 9101


def compute_node(name: str, tier: str, hardware: str, link: dict[str, Any]) -> dict[str, Any]:
    return {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "ComputeNode",
        "metadata": {"name": name},
        # capacity comes from the Node (the bed's real share); the link is the emulated one
        "spec": {"tier": tier, "hardwareType": hardware, "network": [link], "privacyLevel": 3},
    }


def ros_module(
    name: str,
    ns: str,
    *,
    cycle_ms: int,
    taxonomy: tuple[str, str, str],
    subscribes: list[tuple[str, int, int]],
    publishes: list[tuple[str, int, int]],
    profile: list[tuple[str, str, float, float]],
    tiers: list[str] | None = None,
    probe: bool = False,
    **extra: Any,
) -> dict[str, Any]:
    """A SoftwareModule the workload image plays on the bed (:func:`module_object`), with
    ``tiers`` as its requirements and ``probe`` adding the cycle-time sidecar users add to a
    module nobody instrumented."""
    if tiers:
        extra["requirements"] = {"tiers": tiers}
    obj = module_object(
        name, ns, IMAGE, "Never", cycle_ms=cycle_ms, taxonomy=taxonomy, subscribes=subscribes,
        publishes=publishes, rows=list(profile), memory="256Mi", **extra,
    )  # fmt: skip
    if probe:
        obj["spec"]["template"]["sidecars"] = [
            {"name": "cycle-probe", "image": IMAGE, "imagePullPolicy": "Never",
             "args": ["probe", "--port", str(PROBE_PORT)], "metricsPort": PROBE_PORT},
        ]  # fmt: skip
    return obj


def bed_objects(ns: str, fleet: str, modules: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The bed's two robots (Wi-Fi) and edge node (LAN) as ComputeNodes, ``modules``, and a
    RobotFleet ``fleet`` of them with a small, seeded scheduler budget."""
    wifi = {"type": "wifi", "latencyMillis": 4, "jitterMillis": 1, "bandwidthMbps": 100}
    lan = {"type": "lan", "latencyMillis": 1, "jitterMillis": 0, "bandwidthMbps": 1000}
    nodes = [compute_node(r, "robot", "bed-robot", wifi) for r in ROBOTS]
    nodes.append(compute_node(EDGE, "edge", "bed-edge", lan))
    fleet_obj = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "RobotFleet",
        "metadata": {"name": fleet, "namespace": ns},
        "spec": {
            "robots": list(ROBOTS),
            "nodes": [EDGE],
            "modules": [{"name": m["metadata"]["name"]} for m in modules],
            "scheduler": {"population": 20, "generations": 10, "seed": 1},
        },
    }
    return [*nodes, *modules, fleet_obj]


def split_fleet(ns: str, fleet: str = "bedfleet") -> list[dict[str, Any]]:
    """Two robots whose lidar and localizer run on board and whose planner runs on the edge
    (through the robot's discovery server): scan (10 Hz) lidar -> localizer, pose (10 Hz)
    localizer -> planner, across the emulated Wi-Fi link."""
    modules = [
        # the lidar driver: hard real time, stays on its robot
        ros_module("lidar", ns, cycle_ms=100, taxonomy=("periodic", "hard", "critical"),
                   subscribes=[], publishes=[("scan", 4096, 10)],
                   profile=[("bed-robot", "50m", 4, 0.5)]),
        # localization: runs on the robot here
        ros_module("localizer", ns, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
                   subscribes=[("scan", 4096, 10)], publishes=[("pose", 256, 10)],
                   profile=[("bed-robot", "100m", 15, 2), ("bed-edge", "100m", 10, 1)],
                   tiers=["robot"]),
        # the planner: offloaded to the edge, talks to its robot through the discovery server
        ros_module("planner", ns, cycle_ms=1000, taxonomy=("periodic", "soft", "relevant"),
                   subscribes=[("pose", 256, 10)], publishes=[("plan", 2048, 1)],
                   profile=[("bed-robot", "200m", 300, 20), ("bed-edge", "200m", 120, 10)],
                   tiers=["edge"], probe=True),
    ]  # fmt: skip
    return bed_objects(ns, fleet, modules)


@contextmanager
def operated_fleet(
    kube: Kube,
    cluster: Cluster,
    namespace: str,
    tmp_path: Path,
    diagnostics: list[Any],
    objects: list[dict[str, Any]],
    fleet: str,
    env: dict[str, str] | None = None,
) -> Iterator[str]:
    """The operator running (with ``env`` on top of the tests' settings), ``objects`` applied
    and the fleet Ready; yields the namespace."""
    assert set(ROBOTS) | {EDGE} <= set(cluster.real_nodes)
    install_crds(kube)
    op = Operator(kube.kubeconfig, [namespace], tmp_path / "operator.log", env)
    diagnostics.append(lambda: ("operator log", op.logs(150)))
    op.start().wait_live()
    try:
        kube.apply(objects)
        wait_ready(kube, namespace, fleet, timeout=300)
        yield namespace
    finally:
        op.stop()


def scrape(url: str) -> dict[str, float]:
    """Totals per fogfleet metric name (labels summed, buckets left out) from one scrape."""
    return read(url).totals("fogfleet_")


def scrape_series(url: str, name: str, **labels: str) -> float:
    """The sum of the series of metric ``name`` whose labels include ``labels``."""
    return read(url).total(name, **labels)


def scrape_buckets(url: str, name: str, **labels: str) -> dict[float, float]:
    """Histogram ``name``'s cumulative buckets (le -> count) whose labels include ``labels``."""
    return read(url).buckets(name, **labels)
