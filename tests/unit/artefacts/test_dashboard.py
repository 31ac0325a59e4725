"""The chart's Grafana dashboard and alert rules: the fields Grafana needs, expressions that
name only contract metrics, and the chart's copies generated from the builder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

from fogfleet.artefacts import dashboard as dash
from fogfleet.artefacts.files import render_alerts_text
from fogfleet.contract.metrics import OPERATOR_METRICS, WORKLOAD_METRICS

CHART = Path(__file__).resolve().parents[3] / "charts" / "fogfleet"
STATUS_SERIES = {
    "fogfleet_fleet_condition", "fogfleet_fleet_robot_links", "fogfleet_fleet_fallbacks_active",
    "fogfleet_fallback_active",
}  # fmt: skip
KNOWN = {*OPERATOR_METRICS, *WORKLOAD_METRICS, *STATUS_SERIES}


def metric_names(expr: str) -> set[str]:
    """The metric names an expression reads (label names never carry these prefixes)."""
    prefixes = "fogfleet|controller_runtime|workqueue|rest_client"
    return set(re.findall(rf"\b((?:{prefixes})_[a-z0-9_]*)\b", expr))


def base(name: str) -> str:
    return re.sub(r"_(bucket|count|sum)$", "", name)


def test_the_dashboard_has_what_grafana_needs_of_a_dashboard_and_each_panel() -> None:
    model = json.loads((CHART / "dashboards" / "fogfleet.json").read_text())
    assert model == dash.dashboard()
    for key in ("uid", "title", "schemaVersion", "panels", "templating", "time"):
        assert key in model, key
    assert isinstance(model["schemaVersion"], int) and model["schemaVersion"] >= 36
    ids = [p["id"] for p in model["panels"]]
    assert len(ids) == len(set(ids)), "panel ids are unique"
    cells: set[tuple[int, int]] = set()
    for p in model["panels"]:
        grid = p["gridPos"]
        assert {"h", "w", "x", "y"} <= set(grid) and grid["x"] + grid["w"] <= 24
        for dy in range(grid["h"]):
            for dx in range(grid["w"]):
                cell = (grid["x"] + dx, grid["y"] + dy)
                assert cell not in cells, f"{p['title']} overlaps another panel"
                cells.add(cell)
        if p["type"] == "row":
            continue
        assert p["type"] in ("timeseries", "stat", "table")
        assert p["datasource"] == {"type": "prometheus", "uid": "${datasource}"}
        assert p["targets"] and all(t["expr"] and t["refId"] for t in p["targets"])


def test_every_expression_reads_only_metrics_that_exist() -> None:
    exprs = [p.expr for p in dash.panels()] + [a.expr for a in dash.ALERTS]
    for expr in exprs:
        names = metric_names(expr)
        assert names, expr
        assert {base(n) for n in names} <= {base(k) for k in KNOWN}, expr
        assert "$" not in expr, "no Grafana-only variables: the e2e test runs each as it stands"


def test_each_alert_is_its_series_plus_a_threshold() -> None:
    names = {a.name for a in dash.ALERTS}
    assert names == {
        "FogfleetFleetDegraded", "FogfleetFleetDrift", "FogfleetRobotLinkLost",
        "FogfleetFallbacksActive", "FogfleetReconcileErrors",
    }  # fmt: skip
    for a in dash.ALERTS:
        assert a.expr.startswith(a.series) and re.fullmatch(r" (==|>) \d+", a.expr[len(a.series) :])


def test_the_charts_alert_rules_are_the_builders() -> None:
    text = (CHART / "dashboards" / "alerts.yaml").read_text()
    assert text == render_alerts_text()
    (group,) = yaml.safe_load(text)
    assert [r["alert"] for r in group["rules"]] == [a.name for a in dash.ALERTS]
    assert all(r["labels"]["severity"] in ("warning", "critical") for r in group["rules"])
