"""Gene spaces, the link model and the limit rule of build_problem, checked by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.softwaremodule import Taxonomy
from fogfleet.domain.build import build_problem
from fogfleet.domain.network import Link, path
from fogfleet.domain.taxonomy import Offloadability, classify

ROOT = Path(__file__).resolve().parents[3]
WAREHOUSE = ROOT / "manifests" / "examples" / "warehouse"


@pytest.fixture(scope="module")
def warehouse():  # type: ignore[no-untyped-def]
    catalog = load_paths([WAREHOUSE])
    return catalog, build_problem(catalog.fleets[0], catalog)


def test_taxonomy_colours_of_fig_2() -> None:
    assert (
        classify(Taxonomy(execution_pattern="continuous", realtime="hard", safety="relevant"))
        is Offloadability.NEVER
    )
    assert (
        classify(Taxonomy(execution_pattern="event", realtime="soft", safety="critical"))
        is Offloadability.NEVER
    )
    assert (
        classify(Taxonomy(execution_pattern="event", realtime="none", safety="irrelevant"))
        is Offloadability.PREFERRED
    )
    assert (
        classify(Taxonomy(execution_pattern="continuous", realtime="soft", safety="irrelevant"))
        is Offloadability.CANDIDATE
    )


def test_gene_spaces_follow_taxonomy_devices_and_own_robot(warehouse) -> None:  # type: ignore[no-untyped-def]
    _, p = warehouse
    robots = [j for j, n in enumerate(p.nodes) if n.tier.value == "robot"]
    edges = [j for j, n in enumerate(p.nodes) if n.tier.value == "edge"]
    for i, inst in enumerate(p.instances):
        allowed = set(np.flatnonzero(p.allowed[i]))
        own = p.node_index(inst.robot)
        # never another robot's computer (III-E)
        assert allowed & set(robots) <= {own}
        if inst.module in ("nav-controller", "nav-localization"):
            # hard real-time + safety-critical (controller), lidar-bound (localization)
            assert allowed == {own}
        else:
            assert allowed == {own, *edges}


def test_link_model_adds_latency_and_takes_the_narrower_bandwidth() -> None:
    wifi = Link(latency=4e-3, jitter=3e-3, bandwidth=120e6)
    lan = Link(latency=0.3e-3, jitter=4e-3, bandwidth=1e9)
    p = path(wifi, lan)
    assert p.latency == pytest.approx(4.3e-3)
    assert p.jitter == pytest.approx(5e-3)
    assert p.bandwidth == 120e6


def test_transfer_time_of_human_pose_on_an_edge_node(warehouse) -> None:  # type: ignore[no-untyped-def]
    _, p = warehouse
    i = next(k for k, x in enumerate(p.instances) if x.module == "human-pose-estimation")
    j = p.node_index("edge-1")
    # in: 80 KiB image over Wi-Fi 120 Mbit/s + LAN, out: 4 KiB poses (eq. 4)
    t_in = 4.3e-3 + 80 * 1024 * 8 / 120e6
    t_out = 4.3e-3 + 4 * 1024 * 8 / 120e6
    assert p.net_mean[i, j] == pytest.approx(t_in + t_out)
    # on the own robot only the local hop remains
    assert p.net_mean[i, p.home[i]] < 1e-3
    # traffic when offloaded: (80 KiB + 4 KiB) x 10 Hz in bit/s
    assert p.traffic[i] == pytest.approx((80 + 4) * 1024 * 8 * 10)


def test_limit_is_the_smallest_profiled_cpu_that_meets_the_cycle(warehouse) -> None:  # type: ignore[no-untyped-def]
    _, p = warehouse
    i = next(k for k, x in enumerate(p.instances) if x.module == "human-pose-estimation")
    j = p.node_index("edge-1")
    # budget = 0.9 x 100 ms - transfer ~ 15.6 ms = 74.4 ms; 2 cores: 100 + 2x10 > budget,
    # 4 cores: 60 + 2x6 = 72 ms fits -> limit 4 cores, mean 60 ms
    assert p.limits.cpu_request[i, j] == 4
    assert p.limits.exe_mean[i, j] == pytest.approx(0.060)
    # the plain Deployment asks for its nominal 500m and uses all 8 profiled cores
    assert p.nominal.cpu_request[i, j] == 0.5
    assert p.nominal.cpu_use[i, j] == 8
    # F8s v2 nodes have no rows of their own: 'default' rows scaled by speedFactor 1.25
    k = p.node_index("edge-4")
    assert p.limits.exe_mean[i, k] == pytest.approx(p.limits.exe_mean[i, j] / 1.25)


def test_reserved_cpu_is_not_allocatable(warehouse) -> None:  # type: ignore[no-untyped-def]
    _, p = warehouse
    assert p.capacity[p.node_index("robot-1"), 0] == 6  # 8 cores, 2 reserved (paper IV-A)
    assert p.capacity[p.node_index("edge-1"), 0] == 15.5


def test_shared_replicas_are_pinned_to_their_pool_tier(warehouse) -> None:  # type: ignore[no-untyped-def]
    catalog, _ = warehouse
    fleet = catalog.fleets[0]
    module = catalog.module("warehouse", "scene-segmentation")
    shared = module.model_copy(
        update={"spec": module.spec.model_copy(update={"scope": "shared", "replicas": 2})}
    )
    catalog.modules[("warehouse", "scene-segmentation")] = shared
    try:
        p = build_problem(fleet, catalog, pools={"scene-segmentation": {"edge": 3, "cloud": 0}})
    finally:
        catalog.modules[("warehouse", "scene-segmentation")] = module
    replicas = [i for i, x in enumerate(p.instances) if x.module == "scene-segmentation"]
    assert len(replicas) == 3
    for i in replicas:
        assert p.home[i] == -1
        assert {p.nodes[j].tier.value for j in np.flatnonzero(p.allowed[i])} == {"edge"}


def test_current_placement_is_read_back(warehouse) -> None:  # type: ignore[no-untyped-def]
    catalog, _ = warehouse
    p = build_problem(
        catalog.fleets[0],
        catalog,
        current={
            ("robot-2", "scene-segmentation", 0): "edge-5",
            ("robot-2", "nav-controller", 0): "edge-5",
        },
    )
    seg = next(
        i for i, x in enumerate(p.instances) if x == type(x)("robot-2", "scene-segmentation", 0)
    )
    ctrl = next(
        i for i, x in enumerate(p.instances) if x == type(x)("robot-2", "nav-controller", 0)
    )
    assert p.current[seg] == p.node_index("edge-5")
    assert p.current[ctrl] == -1  # not allowed there, so not a valid current placement


def test_growing_the_edge_pool_keeps_a_serving_cloud_replica_in_the_cloud() -> None:
    from fogfleet.api.v1alpha1.common import Tier
    from fogfleet.domain.build import _pool_tiers

    edge, cloud = Tier.EDGE, Tier.CLOUD
    # edge 1 -> 2 while replica 1 serves from the cloud: replica 1 stays there, 2 is the new edge
    assert _pool_tiers({"edge": 2, "cloud": 1}, 1, {0: edge, 1: cloud}) == [edge, cloud, edge]
    # nothing runs yet: edge first
    assert _pool_tiers({"edge": 2, "cloud": 1}, 1) == [edge, edge, cloud]
    # scale-in: more running in the cloud than the pool allows -> the extra gets an edge slot
    assert _pool_tiers({"edge": 1, "cloud": 1}, 1, {0: cloud, 1: cloud}) == [cloud, edge]
    # no pools: spec.replicas, any tier; `any` adds untiered replicas
    assert _pool_tiers(None, 3) == [None, None, None]
    assert _pool_tiers({"any": 2}, 1) == [None, None]


def test_the_fleet_controller_reads_pools_from_the_modules_status() -> None:
    from fogfleet.snapshot.objects import scaling_pools

    modules = [
        {
            "metadata": {"name": "detector"},
            "status": {
                "scaling": {
                    "desiredReplicas": 3,
                    "pools": [{"tier": "edge", "replicas": 2}, {"tier": "cloud", "replicas": 1}],
                }
            },
        },
        {"metadata": {"name": "mapper"}, "status": {"scaling": {"desiredReplicas": 2}}},
        {"metadata": {"name": "camera"}},
    ]
    assert scaling_pools(modules) == {"detector": {"edge": 2, "cloud": 1}, "mapper": {"any": 2}}
