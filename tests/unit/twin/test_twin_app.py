"""The twin's I/O shell with a fake API server: pods in, contract metrics out, load control."""

from __future__ import annotations

import json
import os
import urllib.request
from pathlib import Path
from typing import Any

import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from fogfleet.twin.app import Twin

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "manifests" / "examples" / "shared-detector"
SCENARIO = ROOT / "docs" / "examples" / "twin-scenario.yaml"
NS = "shared-detector"


class FakeKube:
    def __init__(self) -> None:
        self.modules = [
            d for d in yaml.safe_load_all((EXAMPLE / "modules.yaml").read_text())
            if d["metadata"]["name"] == "object-detector"
        ]  # fmt: skip
        self.nodes = [
            {"metadata": {"name": n, "labels": {"fogfleet.io/tier": n.split("-")[0]}}}
            for n in ("edge-1", "edge-2", "cloud-1")
        ]
        self.pods: list[dict[str, Any]] = []
        self.calls: list[str] = []

    def list_pods(self, namespace: str, selector: Any) -> list[dict[str, Any]]:
        self.calls.append(f"pods {namespace} {dict(selector)}")
        return self.pods

    def list_nodes(self) -> list[dict[str, Any]]:
        return self.nodes

    def list_modules(self, namespace: str) -> list[dict[str, Any]]:
        return self.modules if namespace == NS else []

    def run(self, tier: str, n: int, node: str) -> None:
        for k in range(n):
            self.pods.append({
                "metadata": {"name": f"det-{tier}-{k}", "namespace": NS, "labels": {
                    "fogfleet.io/module": "object-detector", "fogfleet.io/tier": tier,
                    "app.kubernetes.io/managed-by": "fogfleet"}},
                "spec": {"nodeName": node},
                "status": {"phase": "Running", "conditions": [
                    {"type": "Ready", "status": "True",
                     "lastTransitionTime": "2026-01-01T00:00:00Z"}]},
            })  # fmt: skip


class Clock:
    def __init__(self) -> None:
        self.t = 1.8e9  # well after the pods became ready

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def twin(tmp_path: Path) -> Any:
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text((SCENARIO).read_text())
    kube, clock = FakeKube(), Clock()
    t = Twin(kube, scenario, port=0, clock=clock)
    t.kube_fake, t.clock_fake = kube, clock  # type: ignore[attr-defined]
    yield t
    t._server.server_close()


def samples(twin: Twin) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    from prometheus_client import generate_latest

    text = generate_latest(twin.metrics.registry).decode()
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for fam in text_string_to_metric_families(text)
        for s in fam.samples
    }


def total(twin: Twin, name: str, **labels: str) -> float:
    return sum(v for (n, lab), v in samples(twin).items()
               if n == name and all(dict(lab).get(k) == x for k, x in labels.items()))  # fmt: skip


def run_for(twin: Twin, seconds: float, step: float = 0.2) -> None:
    for _ in range(int(seconds / step)):
        twin.clock_fake.t += step  # type: ignore[attr-defined]
        twin.step_once()


def test_served_requests_follow_the_running_pods_per_tier(twin: Twin) -> None:
    twin.kube_fake.run("edge", 4, "edge-1")  # type: ignore[attr-defined]
    twin.kube_fake.run("cloud", 2, "cloud-1")  # type: ignore[attr-defined]
    twin.poll_once()
    run_for(twin, 20)
    served = total(twin, "fogfleet_requests_served_total", namespace=NS, module="object-detector")
    assert served == pytest.approx(20 * 20, rel=0.25)  # phase 0: 20 requests/s
    assert total(twin, "fogfleet_requests_served_total", tier="cloud", privacy="private") == 0
    assert total(twin, "fogfleet_replicas", tier="edge", state="ready") == 4
    assert total(twin, "fogfleet_response_time_seconds_count", tier="edge") > 0
    assert all("managed-by" in c for c in twin.kube_fake.calls)  # type: ignore[attr-defined]


def test_without_pods_everything_is_rejected_for_capacity(twin: Twin) -> None:
    twin.poll_once()
    run_for(twin, 5)
    assert total(twin, "fogfleet_requests_rejected_total", reason="capacity") > 50
    assert total(twin, "fogfleet_requests_served_total") == 0


def test_load_can_be_set_over_http_on_loopback(twin: Twin) -> None:
    twin.start()
    try:
        req = urllib.request.Request(
            f"http://127.0.0.1:{twin.port}/load",
            data=json.dumps({"namespace": NS, "module": "object-detector",
                             "requestsPerSecond": 80, "privateShare": 0.5}).encode(),
            method="POST",
        )  # fmt: skip
        assert json.loads(urllib.request.urlopen(req, timeout=5).read()) == {"ok": True}
        rates = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{twin.port}/load").read())
        assert rates[f"{NS}/object-detector"] == {"private": 40.0, "normal": 40.0}
        text = urllib.request.urlopen(f"http://127.0.0.1:{twin.port}/metrics").read().decode()
        assert "fogfleet_requests_rejected_total" in text
        bad = urllib.request.Request(
            f"http://127.0.0.1:{twin.port}/load", data=b"{}", method="POST"
        )
        with pytest.raises(urllib.error.HTTPError) as info:
            urllib.request.urlopen(bad, timeout=5)
        assert info.value.code == 400
    finally:
        twin.stop()


def test_a_changed_scenario_file_is_reloaded_and_a_broken_one_ignored(twin: Twin) -> None:
    path = twin.scenario_path
    doc = yaml.safe_load(path.read_text())
    doc["services"][0]["phases"] = [{"atSeconds": 0, "requestsPerSecond": 5}]
    path.write_text(yaml.safe_dump(doc))
    os.utime(path, (1, 1))
    twin.step_once()
    assert twin.rates(twin.scenario.services[0], twin.clock_fake.t) == pytest.approx((1.5, 3.5))  # type: ignore[attr-defined]
    path.write_text("services: [")
    os.utime(path, (2, 2))
    twin.step_once()
    assert twin.scenario.services[0].phases[0].requests_per_second == 5


def test_the_twin_refuses_to_listen_beyond_loopback(tmp_path: Path) -> None:
    scenario = tmp_path / "s.yaml"
    scenario.write_text((SCENARIO).read_text())
    with pytest.raises(ValueError, match="loopback"):
        Twin(FakeKube(), scenario, port=0, host="0.0.0.0")
