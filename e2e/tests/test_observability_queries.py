"""Every panel of the chart's Grafana dashboard and every alert of its PrometheusRule, sent to
the bed's real Prometheus while a fleet runs on the real nodes and Prometheus scrapes both the
operator's /metrics and the workloads (issue 38).

What "works" means, honestly:

- **parses**: Prometheus answers ``status: success`` for the expression as the chart ships it
  (``Cluster.prometheus_query`` raises otherwise), for panels and alerts alike;
- **returns series**: each panel's expression returns at least one series. An alert's
  expression is empty while the fleet is healthy (no Degraded fleet, no lost link, no
  error), which proves nothing: a misspelt metric or label would be empty too. So for each
  alert the test queries its ``series`` - the same expression without the threshold
  (``artefacts.dashboard.Alert.series``; a unit test checks expr == series + threshold) - and
  requires a series. The alert then fires exactly when that series crosses the threshold.

The expressions are read from the chart's files (``charts/fogfleet/dashboards/``), the ones a
user installs; the alerts' series come from the builder, matched by alert name.

The fleet watches drift (``spec.drift``) and its links (``FOGFLEET_PROMETHEUS_URL``), so its
Drift condition and link states exist; the operator's watch caches are on (the default).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import ROOT, Operator, install_crds, wait_ready
from e2e.tests.rosbed import EDGE, ROBOTS, bed_objects, ros_module
from fogfleet.artefacts.dashboard import ALERTS

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's Prometheus scrapes the operator and the workloads"),
    pytest.mark.real,
    pytest.mark.observability,
    pytest.mark.timeout(600),
]

FLEET = "obsfleet"
DASHBOARDS = ROOT / "charts" / "fogfleet" / "dashboards"
SERIES_TIMEOUT_S = 240  # rate() over [5m] needs two scrapes; planning metrics need a plan


def panel_queries() -> dict[str, str]:
    model = json.loads((DASHBOARDS / "fogfleet.json").read_text())
    out = {}
    for panel in model["panels"]:
        for target in panel.get("targets") or []:
            out[f"panel {panel['title']!r} {target['refId']}"] = target["expr"]
    return out


def alert_queries() -> dict[str, str]:
    (group,) = yaml.safe_load((DASHBOARDS / "alerts.yaml").read_text())
    return {rule["alert"]: rule["expr"] for rule in group["rules"]}


@pytest.fixture
def scraped_fleet(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[str]:
    """A fleet Ready on the real nodes, its operator scraped by the bed's Prometheus."""
    assert set(ROBOTS) | {EDGE} <= set(cluster.real_nodes)
    localizer = ros_module(
        "localizer", namespace, cycle_ms=100, taxonomy=("continuous", "soft", "relevant"),
        subscribes=[], publishes=[("pose", 256, 10)],
        profile=[("bed-robot", "100m", 30, 3), ("bed-edge", "100m", 30, 3)],
    )  # fmt: skip
    localizer["spec"]["resources"]["memory"] = "192Mi"
    objects = bed_objects(namespace, FLEET, [localizer])
    objects[-1]["spec"]["drift"] = {"windowSeconds": 30, "forSeconds": 10}
    install_crds(kube)
    env = {
        "FOGFLEET_PROMETHEUS_URL": cluster.prometheus_url,
        "FOGFLEET_OBSERVE_INTERVAL_SECONDS": "5",
    }
    op = Operator(kube.kubeconfig, [namespace], tmp_path / "operator.log", env)
    diagnostics.append(lambda: ("operator log", op.logs(150)))
    op.start().wait_live()
    target = f"fogfleet-operator-{namespace}"
    try:
        cluster.add_prometheus_target(target, f"127.0.0.1:{op.metrics_port}")
        kube.apply(objects)
        wait_ready(kube, namespace, FLEET, timeout=300)
        yield namespace
    finally:
        cluster.remove_prometheus_target(target)
        op.stop()


def test_every_dashboard_and_alert_query_parses_and_returns_series(
    cluster: Cluster, scraped_fleet: str
) -> None:
    panels, alerts = panel_queries(), alert_queries()
    series = {a.name: a.series for a in ALERTS}
    assert set(alerts) == set(series), "the chart's alerts are the builder's"
    for name, expr in alerts.items():
        assert expr.startswith(series[name]), name
        cluster.prometheus_query(expr)  # parses (raises on a Prometheus error)
    wanted = {**panels, **{f"alert {n} (without its threshold)": s for n, s in series.items()}}
    missing = dict(wanted)
    deadline = time.monotonic() + SERIES_TIMEOUT_S
    while missing and time.monotonic() < deadline:
        for name, expr in list(missing.items()):
            if cluster.prometheus_query(expr):  # parses, and returns at least one series
                del missing[name]
        if missing:
            time.sleep(5)
    lines = "\n".join(f"{k}: {v}" for k, v in missing.items())
    assert not missing, f"no series after {SERIES_TIMEOUT_S}s:\n{lines}"
    # the operator's own series carry this fleet: its Ready condition as the API has it (the
    # fleet may re-plan meanwhile, so compare with the API until a scrape agrees, at most 60 s)
    query = (
        f'fogfleet_fleet_condition{{fleet_namespace="{scraped_fleet}",fleet="{FLEET}",'
        'type="Ready"} == 1'
    )
    seen: tuple[str | None, list[Any]] = (None, [])
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        body = cluster.kubectl_json("get", "robotfleet", FLEET, "-n", scraped_fleet)
        ready = next(
            (c["status"] for c in body["status"]["conditions"] if c["type"] == "Ready"), None
        )
        rows = cluster.prometheus_query(query)
        seen = (ready, rows)
        if [r["metric"].get("status") for r in rows] == [ready]:
            break
        time.sleep(5)
    else:
        raise AssertionError(f"Ready in the API and in the metric disagree for 60 s: {seen}")
    writes = cluster.prometheus_query(
        'sum(rest_client_requests_total{method=~"POST|PUT|PATCH|DELETE"})'
    )
    assert writes and float(writes[0]["value"][1]) > 0, "the fleet's rollout wrote to the API"
