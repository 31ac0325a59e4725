"""The whole SLO loop: the operator, as a process on the host or installed in-cluster by its
chart (issue 44), decides on its own from the bed's Prometheus, and the fleet controller places
the new replicas, the edge pool before the cloud's. The twin serves the load (``scaling_rig``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    OPERATOR_LABELS,
    Operator,
    example_in,
    of_kind,
)
from e2e.tests.incluster import SYSTEM, installed
from e2e.tests.scaling_rig import (
    DOWN_POLICY,
    MODULE,
    PERIOD,
    UP_POLICY,
    Rig,
    Seen,
    delete_fleet_objects,
    look,
    start_twin,
    tier_of,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus (file_sd targets) and its kwok warehouse nodes"),
    pytest.mark.timeout(300),
]

Obj = dict[str, Any]

EDGE_MAX, CLOUD_MAX = 2, 4
# Decisions come within seconds; the pods follow as fast as kube-controller-manager creates
# them, which takes tens of seconds while another suite churns hundreds of Deployments.
START_TIMEOUT = PODS_TIMEOUT = 60


def _loop_docs(namespace: str) -> tuple[list[Obj], list[Obj], Obj]:
    """The shared-detector example in ``namespace`` with a small edge pool and short windows:
    (ComputeNodes, modules, fleet). The robot and edge ComputeNodes are the warehouse's."""
    shared = example_in("shared-detector", namespace)
    fleet_body = of_kind(shared, "RobotFleet")[0]
    names = set(fleet_body["spec"]["robots"]) | set(fleet_body["spec"]["nodes"])
    nodes = [d for d in of_kind(shared, "ComputeNode") if d["metadata"]["name"] in names]
    modules = of_kind(shared, "SoftwareModule")
    detector = next(m for m in modules if m["metadata"]["name"] == MODULE)
    detector["spec"]["replicas"] = 1
    detector["spec"]["scaling"].update(
        {
            "maxReplicas": EDGE_MAX + CLOUD_MAX,
            "behavior": {
                "scaleUp": {"stabilizationWindowSeconds": 0, "policies": [UP_POLICY]},
                # no scale-down while the test runs: each step only adds replicas
                "scaleDown": {"stabilizationWindowSeconds": 300, "policies": [DOWN_POLICY]},
            },
            "pools": [
                {"tier": "edge", "maxReplicas": EDGE_MAX, "setupMillis": 1000},
                {"tier": "cloud", "maxReplicas": CLOUD_MAX, "setupMillis": 2000,
                 "sloTargetMillis": 500},
            ],
        }
    )  # fmt: skip
    return nodes, modules, fleet_body


@contextmanager
def scaling_operator(
    where: str, kube: Kube, cluster: Cluster, namespace: str, log: Path
) -> Iterator[Callable[[int], str]]:
    """The operator watching ``namespace`` with its Prometheus, deciding every PERIOD: a process
    on the host reading Prometheus at 127.0.0.1, or installed in-cluster by its chart (issue
    44) reading it at its cluster address, as users run it; yields its log's last lines."""
    if where == "process":
        op = Operator(
            kube.kubeconfig,
            [namespace],
            log,
            env={
                "FOGFLEET_PROMETHEUS_URL": cluster.prometheus_url,
                "FOGFLEET_SCALING_INTERVAL_SECONDS": str(int(PERIOD)),
            },
        )
        op.start().wait_live()
        try:
            yield op.logs
        finally:
            # while the operator runs: it removes its finalizers
            delete_fleet_objects(kube, namespace)
            op.stop()
        return
    values = {
        "scaling.prometheusUrl": cluster.in_cluster_prometheus_url,
        "scaling.intervalSeconds": str(int(PERIOD)),
    }
    with installed(kube, values=values, namespace=namespace):

        def logs(lines: int) -> str:
            return kube.kubectl("logs", "-n", SYSTEM, "-l", OPERATOR_LABELS, f"--tail={lines}",
                                "--prefix", check=False).stdout  # fmt: skip

        try:
            yield logs
        finally:
            delete_fleet_objects(kube, namespace)


@pytest.mark.timeout(420)
@pytest.mark.parametrize(
    "where",
    [
        "process",
        pytest.param("incluster", marks=[pytest.mark.inclusterloop, pytest.mark.incluster]),
    ],
)
def test_operator_scales_a_shared_service_and_places_new_replicas_on_the_edge_first(
    where: str,
    kube: Kube,
    cluster: Cluster,
    crds: None,
    rig: Rig,
    tmp_path: Path,
    diagnostics: list[Any],
) -> None:
    namespace = rig.namespace
    nodes, modules, fleet_body = _loop_docs(namespace)
    kube.apply(nodes + modules)
    kube.apply(fleet_body)
    operator = scaling_operator(where, kube, cluster, namespace, tmp_path / "operator.log")
    seen: list[Seen] = []
    logs: list[Callable[[int], str]] = []
    diagnostics.append(lambda: ("operator log", logs[0](200) if logs else ""))
    diagnostics.append(
        lambda: ("what the test saw", "\n".join(
            f"{s.t:5.1f}s pools={s.pools} deployments={s.deployments} pods={s.pods}"
            for s in seen))
    )  # fmt: skip
    t0 = time.monotonic()

    def until(what: str, check: Any, timeout: float) -> Seen:
        deadline = time.monotonic() + timeout
        while True:
            s = look(kube, namespace, t0)
            if not seen or s.key() != seen[-1].key():
                seen.append(s)
            if check(s):
                return s
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:.0f}s waiting for {what}: {s}")
            time.sleep(1.0)

    def settled(edge: int, cloud: int) -> Any:
        """The decision is (edge, cloud) and that many replicas run on each tier, where planned."""

        def check(s: Seen) -> bool:
            placed = sorted(tier_of(n) for n in s.deployments.values())
            return (
                s.pools == {"edge": edge, "cloud": cloud}
                and placed == ["cloud"] * cloud + ["edge"] * edge
                and len(s.on("edge")) == edge
                and len(s.on("cloud")) == cloud
                and len(s.pods) == edge + cloud
            )

        return check

    with operator as operator_logs:
        logs.append(operator_logs)
        # before any metrics: the starting pools, edge 1 (spec.replicas) + cloud 1 (minReplicas)
        start = until("the starting replicas to run", settled(1, 1), timeout=START_TIMEOUT)
        start_twin(rig, tmp_path, rate=0.5)
        kube.wait_for(
            "a decision on real metrics",
            lambda: rig.scaling().get("metricsAvailable") is True,
            timeout=20,
        )
        assert rig.scaling()["desiredReplicas"] == 2, rig.scaling()

        # a moderate load: one more replica, on the edge (its pool is below its max)
        rig.set_load(4.0)
        edge_full = until("the edge pool to fill", settled(EDGE_MAX, 1), timeout=PODS_TIMEOUT)
        assert rig.events("ScaledUp")

        # a surge: the edge pool is full, so the new replicas go to cloud-1
        rig.set_load(12.0)
        surge = until("replicas in the cloud", settled(EDGE_MAX, CLOUD_MAX), timeout=PODS_TIMEOUT)
        up = rig.events("ScaledUp")
    print(
        f"edge first: {start.pools} at {start.t:.0f}s -> {edge_full.pools} at "
        f"{edge_full.t:.0f}s -> {surge.pools} at {surge.t:.0f}s; "
        f"pods {sorted(surge.pods.values())}; ScaledUp: "
        + "; ".join(e["message"].split(":")[0] for e in up)
    )
    assert len(up) >= 2, up
    # the decisions never grew the cloud pool while the edge pool had room
    for s in seen:
        if s.pools.get("cloud", 0) > 1:
            assert s.pools["edge"] == EDGE_MAX, s
    # the surge's new replicas all went to cloud-1, the edge ones stayed where they were
    added = set(surge.deployments) - set(edge_full.deployments)
    assert len(added) == CLOUD_MAX - 1 and {surge.deployments[d] for d in added} == {"cloud-1"}
    assert all(surge.deployments[d] == n for d, n in edge_full.deployments.items()), (
        edge_full.deployments,
        surge.deployments,
    )
    # Growing the edge pool must add an edge replica and leave the running cloud replica alone.
    added = set(edge_full.deployments) - set(start.deployments)
    moved = {
        d: f"{n} -> {edge_full.deployments[d]}"
        for d, n in start.deployments.items()
        if edge_full.deployments.get(d) != n
    }
    cloud_while_edge_had_room = [
        s for s in seen if len(s.on("cloud")) > 1 and len(s.on("edge")) < EDGE_MAX
    ]
    assert added and {tier_of(edge_full.deployments[d]) for d in added} == {"edge"}, (
        start.deployments,
        edge_full.deployments,
    )
    assert not moved, moved
    assert not cloud_while_edge_had_room, cloud_while_edge_had_room
