"""The SLO scaler's rig for the autoscaling e2e tests (``test_autoscaling``,
``test_autoscaling_loop``): the scaling controller driven in-process, one decision at a time
(``reconcile_scaling`` every ``PERIOD`` seconds, as the kopf timer does), against the real API
server and the bed's real Prometheus, which scrapes the twin on 127.0.0.1 (file_sd target).
A stand-in places each pool as one Deployment pinned to its tier; kube-scheduler binds the pods
and kwok runs them, and the twin serves requests on the pods that run.
"""

from __future__ import annotations

import copy
import json
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import EXAMPLES, bound_node, free_port
from fogfleet.adapters.kube import KubeClient, load_config
from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.controllers.module.scaling import ScalingDeps, reconcile_scaling
from fogfleet.render.ros import PLANNED_TOLERATION
from fogfleet.twin.app import Twin

__all__ = [
    "DOWN_POLICY",
    "DOWN_WINDOW",
    "MODULE",
    "PERIOD",
    "UP_POLICY",
    "Rig",
    "Seen",
    "delete_fleet_objects",
    "look",
    "module_body",
    "scaling_rig",
    "start_twin",
    "tier_of",
    "total",
]

MODULE = "object-detector"
PERIOD = 2.0  # seconds between decisions (Prometheus scrapes every 2 s)
UP_POLICY: dict[str, Any] = {"type": "Pods", "value": 4, "periodSeconds": 4}
DOWN_WINDOW = 16
DOWN_POLICY: dict[str, Any] = {"type": "Pods", "value": 1, "periodSeconds": 6}
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


def twin_scenario(path: Path, namespace: str, rate: float) -> Path:
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


@contextmanager
def scaling_rig(
    kube: Kube, cluster: Cluster, namespace: str, diagnostics: list[Any]
) -> Iterator[Rig]:
    """A ``Rig`` in ``namespace``: the scaler's dependencies on the bed's API server and
    Prometheus; its twin (if started) stopped and unscraped after."""
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
    try:
        yield r
    finally:
        if r.twin is not None:
            cluster.remove_prometheus_target(f"twin-{namespace}")
            r.twin.stop()


def start_twin(rig: Rig, tmp_path: Path, rate: float) -> None:
    """The twin serving ``rate`` requests/s on the pods that run, scraped by Prometheus."""
    twin = Twin(
        KubeClient(load_config(str(rig.kube.kubeconfig))),
        twin_scenario(tmp_path / "scenario.yaml", rig.namespace, rate),
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
        return sorted(n for n in self.pods.values() if tier_of(n) == tier)


def tier_of(node: str) -> str:
    """The bed's tier of a kwok node, by its name."""
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


def delete_fleet_objects(kube: Kube, namespace: str) -> None:
    for kind in ("robotfleets", "softwaremodules"):
        kube.kubectl("delete", kind, "--all", "-n", namespace, "--wait=true",
                     "--timeout=60s", check=False, timeout=90)  # fmt: skip
