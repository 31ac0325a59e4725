"""SLO-driven autoscaling end to end: the real Prometheus of the harness scrapes the twin on
127.0.0.1 (file_sd target), the scaling controller decides against the real API server.

The controller is driven in-process (``reconcile_scaling`` every ``PERIOD`` seconds, as the kopf
timer does), with short windows in the test's ScalingSpec so the suite stays fast. The
RobotFleet controller does not read ``status.scaling.pools`` yet, so a stand-in places each
pool as one Deployment pinned to its tier (``nodeSelector fogfleet.io/tier``); kube-scheduler
binds the pods and kwok runs them, and the twin serves requests on the pods that run.
"""

from __future__ import annotations

import copy
import itertools
import json
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    EXAMPLES,
    OPERATOR_LABELS,
    Operator,
    bound_node,
    example_in,
    free_port,
    of_kind,
)
from e2e.tests.incluster import SYSTEM, installed
from fogfleet.adapters.kube import KubeClient, load_config
from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.controllers.scaling import ScalingDeps, reconcile_scaling
from fogfleet.render.ros import PLANNED_TOLERATION
from fogfleet.twin.app import Twin

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus (file_sd targets) and its kwok warehouse nodes"),
    pytest.mark.timeout(300),
]  # ticks are slower on a loaded 2-core bed

MODULE = "object-detector"
PERIOD = 2.0  # seconds between decisions (Prometheus scrapes every 2 s)
UP_POLICY = {"type": "Pods", "value": 4, "periodSeconds": 4}
DOWN_WINDOW = 16
DOWN_POLICY = {"type": "Pods", "value": 1, "periodSeconds": 6}
Obj = dict[str, Any]


def module_body(namespace: str, **scaling: Any) -> Obj:
    docs = yaml.safe_load_all((EXAMPLES / "shared-detector" / "modules.yaml").read_text())
    body: Obj = copy.deepcopy(next(d for d in docs if d["metadata"]["name"] == MODULE))
    body["metadata"]["namespace"] = namespace
    body["spec"]["replicas"] = 1
    body["spec"]["scaling"].update(
        {
            "behavior": {
                "scaleUp": {"stabilizationWindowSeconds": 0, "policies": [UP_POLICY]},
                "scaleDown": {
                    "stabilizationWindowSeconds": DOWN_WINDOW,
                    "policies": [DOWN_POLICY],
                },
            },
            "pools": [
                {"tier": "edge", "maxReplicas": 6, "setupMillis": 1000},
                {"tier": "cloud", "maxReplicas": 6, "setupMillis": 2000},
            ],
            **scaling,
        }
    )
    return body


@dataclass
class Rig:
    """One namespace's scaler, twin and placement stand-in."""

    kube: Kube
    cluster: Cluster
    namespace: str
    deps: ScalingDeps
    twin: Twin | None = None
    history: list[tuple[float, dict[str, int]]] = field(default_factory=list)

    def module(self) -> Obj:
        out: Obj = self.kube.kubectl_json("get", "softwaremodule", MODULE, "-n", self.namespace)
        return out

    def tick(self) -> Obj:
        """One decision, then place its pools; returns the module's status."""
        module = self.module()
        # the history keeps the time the policy decided at, not when the test read the result:
        # on a loaded machine the reads between them take a varying second or more
        now, at = time.time(), time.monotonic()
        reconcile_scaling(module, self.deps, now)
        status: Obj = self.module().get("status") or {}
        pools = {p["tier"]: p["replicas"] for p in (status.get("scaling") or {}).get("pools", [])}
        self.history.append((at, pools))
        self.place(pools)
        return status

    def place(self, pools: dict[str, int]) -> None:
        for tier, replicas in pools.items():
            labels = {
                "app.kubernetes.io/managed-by": "fogfleet",
                "fogfleet.io/module": MODULE,
                "fogfleet.io/tier": tier,
                "fogfleet.io/instance": f"{MODULE}-{tier}",
            }
            self.deps.kube.apply_deployment(  # type: ignore[attr-defined]
                {
                    "apiVersion": "apps/v1",
                    "kind": "Deployment",
                    "metadata": {
                        "name": f"{MODULE}-{tier}",
                        "namespace": self.namespace,
                        "labels": labels,
                    },
                    "spec": {
                        "replicas": replicas,
                        "selector": {"matchLabels": {"fogfleet.io/instance": labels[
                            "fogfleet.io/instance"]}},
                        "template": {
                            "metadata": {"labels": labels},
                            "spec": {
                                "nodeSelector": {"fogfleet.io/tier": tier},
                                "tolerations": [PLANNED_TOLERATION],
                                "containers": [{"name": "detector", "image": "detector:e2e"}],
                                "enableServiceLinks": False,
                            },
                        },
                    },
                }
            )  # fmt: skip

    def set_load(self, rate: float, private_share: float = 0.3) -> None:
        assert self.twin is not None
        req = urllib.request.Request(
            f"http://127.0.0.1:{self.twin.port}/load",
            data=json.dumps(
                {"namespace": self.namespace, "module": MODULE,
                 "requestsPerSecond": rate, "privateShare": private_share}
            ).encode(),
            method="POST",
        )  # fmt: skip
        with urllib.request.urlopen(req, timeout=5) as r:
            assert r.status == 200

    def scaling(self) -> Obj:
        return dict((self.module().get("status") or {}).get("scaling") or {})

    def conditions(self) -> dict[str, Obj]:
        return {c["type"]: c for c in (self.module().get("status") or {}).get("conditions", [])}

    def events(self, reason: str) -> list[Obj]:
        sel = f"involvedObject.name={MODULE},reason={reason}"
        items: list[Obj] = self.kube.kubectl_json(
            "get", "events", "-n", self.namespace, "--field-selector", sel
        )["items"]
        return items

    def ticks_until(self, what: str, check: Any, timeout: float) -> Obj:
        deadline = time.monotonic() + timeout
        while True:
            status = self.tick()
            if check(status):
                return status
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"timed out after {timeout:.0f}s waiting for {what}; last status:\n"
                    + json.dumps(status, indent=1)
                )
            time.sleep(PERIOD)


def _scenario(path: Path, namespace: str, rate: float) -> Path:
    path.write_text(
        yaml.safe_dump(
            {
                "services": [
                    {
                        "module": MODULE,
                        "namespace": namespace,
                        "privateShare": 0.3,
                        "phases": [{"atSeconds": 0, "requestsPerSecond": rate}],
                    }
                ]
            }
        )
    )
    return path


@pytest.fixture
def rig(
    kube: Kube, cluster: Cluster, crds: None, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[Rig]:
    api = load_config(str(kube.kubeconfig))
    deps = ScalingDeps(
        KubeClient(api),
        PrometheusClient(cluster.prometheus_url),
        period_seconds=PERIOD,
        slo_window_seconds=10,
        rate_window_seconds=6,
    )
    r = Rig(kube, cluster, namespace, deps)
    diagnostics.append(lambda: ("scaling history", "\n".join(f"{t:.1f} {p}" for t, p in r.history)))
    yield r
    if r.twin is not None:
        cluster.remove_prometheus_target(f"twin-{namespace}")
        r.twin.stop()


def start_twin(rig: Rig, tmp_path: Path, rate: float) -> None:
    from fogfleet.adapters.kube import KubeClient

    twin = Twin(
        KubeClient(load_config(str(rig.kube.kubeconfig))),
        _scenario(tmp_path / "scenario.yaml", rig.namespace, rate),
        port=free_port(),
        namespace=rig.namespace,
        poll_seconds=0.5,
        seed=7,
    ).start()
    rig.twin = twin
    rig.cluster.add_prometheus_target(f"twin-{rig.namespace}", f"127.0.0.1:{twin.port}")
    sel = f'module="{MODULE}",namespace="{rig.namespace}"'
    rig.kube.wait_for(
        "Prometheus to scrape the twin",
        lambda: bool(rig.cluster.prometheus_query(f"fogfleet_requests_served_total{{{sel}}}")),
        timeout=30,
    )


def total(pools: dict[str, int]) -> int:
    return sum(pools.values())


def test_load_step_scales_up_within_the_window_and_down_after_stabilisation(
    rig: Rig, tmp_path: Path
) -> None:
    rig.kube.apply(module_body(rig.namespace))
    rig.tick()  # the first decision places the starting pools (edge 1, cloud 1)
    start_twin(rig, tmp_path, rate=4.0)
    base = rig.ticks_until(
        "a decision on real metrics",
        lambda s: (s.get("scaling") or {}).get("metricsAvailable") is True,
        timeout=30,
    )["scaling"]["desiredReplicas"]

    rig.set_load(60.0)
    t_step = time.monotonic()
    up = rig.ticks_until(
        "a scale-up after the load step",
        lambda s: s["scaling"]["desiredReplicas"] > base,
        timeout=6 + 2 * PERIOD + 10,  # rate window + scrape + decision, with slack
    )
    took = time.monotonic() - t_step
    print(f"scale-up {base} -> {up['scaling']['desiredReplicas']} after {took:.1f}s")
    assert rig.events("ScaledUp")
    assert {c: v["status"] for c, v in rig.conditions().items()} == {
        "Scaling": "True",
        "MetricsUnavailable": "False",
    }
    # the predictive sizing fills the edge pool before the cloud's (here, edge max 6)
    settled = rig.ticks_until(
        "the edge pool to fill",
        lambda s: {p["tier"]: p["replicas"] for p in s["scaling"]["pools"]}["edge"] == 6,
        timeout=20,
    )
    peak = settled["scaling"]["desiredReplicas"]
    assert peak > 6, settled  # 60 requests/s need the cloud too

    rig.set_load(2.0)
    t_fall = time.monotonic()
    rig.ticks_until(
        "the first scale-down",
        lambda s: s["scaling"]["desiredReplicas"] < peak,
        timeout=DOWN_WINDOW + 6 + 20,
    )
    first_down = time.monotonic() - t_fall
    print(f"first scale-down {first_down:.1f}s after the load fell")
    assert first_down >= DOWN_WINDOW  # not before the stabilisation window
    for _ in range(int(2 * DOWN_POLICY["periodSeconds"] / PERIOD) + 1):
        time.sleep(PERIOD)
        rig.tick()
    # at most `value` pods removed per pool and policy period
    after = [(t, p) for t, p in rig.history if t >= t_fall]
    for tier in ("edge", "cloud"):
        for (t1, a), (t2, b) in itertools.combinations(after, 2):
            if t2 - t1 < DOWN_POLICY["periodSeconds"] - 0.5:
                assert a[tier] - b[tier] <= DOWN_POLICY["value"], (tier, after)
    assert total(after[-1][1]) < peak
    assert rig.events("ScaledDown")


def test_prometheus_unreachable_holds_then_scaling_resumes(rig: Rig, tmp_path: Path) -> None:
    rig.kube.apply(module_body(rig.namespace))
    rig.tick()
    start_twin(rig, tmp_path, rate=4.0)
    held = rig.ticks_until(
        "a decision on real metrics",
        lambda s: (s.get("scaling") or {}).get("metricsAvailable") is True,
        timeout=30,
    )["scaling"]["desiredReplicas"]
    live = rig.deps.prometheus
    dead_port = free_port()  # nothing listens there
    rig.deps.prometheus = PrometheusClient(f"http://127.0.0.1:{dead_port}")
    rig.set_load(60.0)  # would scale up, if the scaler could see it
    for _ in range(4):
        status = rig.tick()
        assert status["scaling"]["desiredReplicas"] == held
        assert status["scaling"]["metricsAvailable"] is False
        time.sleep(PERIOD)
    cond = rig.conditions()["MetricsUnavailable"]
    assert (cond["status"], cond["reason"]) == ("True", "PrometheusUnreachable")
    assert f"127.0.0.1:{dead_port}" in cond["message"]
    assert rig.conditions()["Scaling"]["status"] == "False"
    # one Warning for the outage (another came earlier, for the NoData before the twin ran)
    outage = [e for e in rig.events("MetricsUnavailable") if str(dead_port) in e["message"]]
    assert len(outage) == 1 and outage[0]["type"] == "Warning"
    assert not rig.events("ScaledUp")

    rig.deps.prometheus = live
    rig.ticks_until(
        "scaling to resume", lambda s: s["scaling"]["desiredReplicas"] > held, timeout=20
    )
    assert rig.conditions()["MetricsUnavailable"]["status"] == "False"


def test_a_bad_slo_query_is_reported_precisely_and_nothing_scales(rig: Rig) -> None:
    query = (
        "histogram_quantile(0.99, sum by (le) (rate(fogfleet_response_time_seconds_bucket[10s]))"
    )
    slo = {"query": query, "targetMillis": 350}
    rig.kube.apply(module_body(rig.namespace, mode="reactive", slo=slo))
    for _ in range(2):
        status = rig.tick()
        time.sleep(0.5)
    assert status["scaling"]["desiredReplicas"] == 2  # edge 1 + cloud 1, as started
    cond = rig.conditions()["MetricsUnavailable"]
    assert (cond["status"], cond["reason"]) == ("True", "InvalidSLOQuery")
    assert cond["message"].startswith("spec.scaling.slo.query: ")
    assert "parse error" in cond["message"] and query in cond["message"]
    events = rig.events("InvalidSLOQuery")
    assert len(events) == 1 and events[0]["type"] == "Warning"
    assert "parse error" in events[0]["message"]
    assert not rig.events("ScaledUp") and not rig.events("ScaledDown")


# --------------------------------------------------------------------------- the whole loop

EDGE_MAX, CLOUD_MAX = 2, 4
# Decisions come within seconds; the pods follow as fast as kube-controller-manager creates
# them, which takes tens of seconds while another suite churns hundreds of Deployments.
START_TIMEOUT = PODS_TIMEOUT = 60


def _loop_docs(namespace: str) -> tuple[list[Obj], Obj, Obj]:
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


@dataclass
class Seen:
    """One look at the cluster: the decision, the replica Deployments and where pods run."""

    t: float
    pools: dict[str, int]
    deployments: dict[str, str]  # Deployment -> the node its affinity names
    pods: dict[str, str]  # Running pod -> node

    def key(self) -> tuple[Any, ...]:
        return self.pools, self.deployments, self.pods

    def on(self, tier: str) -> list[str]:
        return sorted(n for n in self.pods.values() if _tier(n) == tier)


def _tier(node: str) -> str:
    return "cloud" if node.startswith("cloud-") else "edge" if node.startswith("edge-") else "?"


def look(kube: Kube, namespace: str, t0: float) -> Seen:
    mod = kube.kubectl_json("get", "softwaremodule", MODULE, "-n", namespace)
    scaling = (mod.get("status") or {}).get("scaling") or {}
    pools = {p["tier"]: p["replicas"] for p in scaling.get("pools") or []}
    sel = f"fogfleet.io/module={MODULE}"
    deps = {
        d["metadata"]["name"]: ",".join(bound_node(d))
        for d in kube.kubectl_json("get", "deployments", "-n", namespace, "-l", sel)["items"]
    }
    pods = {
        p["metadata"]["name"]: p["spec"].get("nodeName", "")
        for p in kube.kubectl_json("get", "pods", "-n", namespace, "-l", sel)["items"]
        if p["status"].get("phase") == "Running" and not p["metadata"].get("deletionTimestamp")
    }
    return Seen(time.monotonic() - t0, pools, deps, pods)


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


def delete_fleet_objects(kube: Kube, namespace: str) -> None:
    for kind in ("robotfleets", "softwaremodules"):
        kube.kubectl("delete", kind, "--all", "-n", namespace, "--wait=true",
                     "--timeout=60s", check=False, timeout=90)  # fmt: skip


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
            placed = sorted(_tier(n) for n in s.deployments.values())
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
    assert added and {_tier(edge_full.deployments[d]) for d in added} == {"edge"}, (
        start.deployments,
        edge_full.deployments,
    )
    assert not moved, moved
    assert not cloud_while_edge_had_room, cloud_while_edge_had_room
