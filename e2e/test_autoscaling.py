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
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.cluster.harness import Cluster
from e2e.cluster.kube import Kube
from e2e.operator_fixtures import CRDS, EXAMPLES, free_port
from fogfleet.adapters.kube import KubeClient, load_config
from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.controllers.scaling import ScalingDeps, reconcile_scaling
from fogfleet.twin.app import Twin

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

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
        reconcile_scaling(self.module(), self.deps, time.time())
        status: Obj = self.module().get("status") or {}
        pools = {p["tier"]: p["replicas"] for p in (status.get("scaling") or {}).get("pools", [])}
        self.history.append((time.monotonic(), pools))
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


@pytest.fixture(scope="module")
def crds(kube: Kube) -> None:
    kube.kubectl("apply", "--server-side", "--force-conflicts", "-f", str(CRDS))
    kube.kubectl(
        "wait", "--for=condition=Established", "crd/softwaremodules.fogfleet.io", "--timeout=60s"
    )


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
