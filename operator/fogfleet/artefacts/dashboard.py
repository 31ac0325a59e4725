"""The Grafana dashboard and the alert rules the Helm chart ships, built over the metrics contract.

One builder for both, so every expression names a metric ``contract.metrics`` lists (a unit test
checks it) and the chart's copies (``charts/fogfleet/dashboards/``) are generated, never edited:
``make crds`` writes them and ``make crds-check`` fails on drift. The e2e test
``test_observability_queries.py`` sends every expression to the bed's real Prometheus.

Rows of the dashboard: **Fleets** (conditions, robots' links, standbys computing on board,
instances planned below their deadline's CPU), **Modules** (measured miss rate and cycle time
from the workloads' own histograms, standbys per module) and **Operator** (reconciles by
result, their p95 time and errors, queue depth, API requests and writes per second, watch
restarts, planning time). Expressions use plain ``[5m]`` windows, no Grafana-only variables,
so each one runs as it stands in Prometheus.

Each alert keeps ``series``: the expression without its threshold. An alert is empty while
all is well; its ``series`` is not, as long as what it watches exists (the e2e test checks
that, so an alert on a misspelt metric or label cannot sit silent forever).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from fogfleet.contract.metrics import (
    API_REQUESTS,
    CYCLE_TIME,
    MISSED_CYCLES,
    RECONCILE_ERRORS,
    RECONCILE_TIME,
    RECONCILE_TOTAL,
    WATCH_RESTARTS,
    WORKQUEUE_DEPTH,
)

__all__ = [
    "ALERTS",
    "DASHBOARD_UID",
    "Alert",
    "Panel",
    "alert_rules",
    "dashboard",
    "dashboard_json",
    "panels",
]

Json = dict[str, Any]
DASHBOARD_UID = "fogfleet-overview"
SCHEMA_VERSION = 39  # Grafana 10.4+ reads it (and migrates older dashboards to it)
DATASOURCE = {"type": "prometheus", "uid": "${datasource}"}
WRITES = 'method=~"POST|PUT|PATCH|DELETE"'
CONDITION = "fogfleet_fleet_condition"
LINKS = "fogfleet_fleet_robot_links"
FALLBACKS = "fogfleet_fleet_fallbacks_active"


@dataclass(frozen=True)
class Panel:
    title: str
    expr: str
    legend: str
    unit: str = "short"
    description: str = ""
    kind: str = "timeseries"


@dataclass(frozen=True)
class Alert:
    name: str
    expr: str
    series: str
    """The expression without its threshold: empty only when what it watches is missing."""
    for_: str
    summary: str
    description: str
    severity: str = "warning"


def _miss_rate() -> str:
    by = "sum by (namespace, module)"
    return f"{by} (rate({MISSED_CYCLES}[5m])) / {by} (rate({CYCLE_TIME}_count[5m]))"


ROWS: tuple[tuple[str, tuple[Panel, ...]], ...] = (
    (
        "Fleets",
        (
            Panel(
                "Conditions that are True",
                f'sum by (fleet_namespace, fleet, type) ({CONDITION}{{status="True"}})',
                "{{fleet_namespace}}/{{fleet}} {{type}}",
                description="1 while a fleet's condition (Ready, Scheduled, Degraded, Drift) "
                "is True: Ready should be 1, Degraded and Drift 0.",
            ),
            Panel(
                "Robots by link state",
                f"sum by (fleet, state) ({LINKS})",
                "{{fleet}} {{state}}",
                description="Robots whose link is Healthy, Degraded, Recovering, Lost or "
                "Unknown (fleets whose links are monitored).",
            ),
            Panel(
                "Standbys computing on board",
                f"sum by (fleet) ({FALLBACKS})",
                "{{fleet}}",
                description="On-board fallbacks computing their module's outputs now (each "
                "means a remote instance is unreachable).",
            ),
            Panel(
                "Instances below their deadline's CPU",
                "sum by (fleet) (fogfleet_degraded_instances)",
                "{{fleet}}",
                description="Instances the last plan runs with less CPU than their deadline "
                "needs (the cluster is short of capacity).",
            ),
        ),
    ),
    (
        "Modules",
        (
            Panel(
                "Measured miss rate",
                _miss_rate(),
                "{{namespace}}/{{module}}",
                unit="percentunit",
                description="Missed cycles / cycles over 5 minutes, from the workloads' own "
                "counters; compare with the fleet's status.predictedMissRate.",
            ),
            Panel(
                "Cycle time p95",
                f"histogram_quantile(0.95, sum by (le, module, tier) "
                f"(rate({CYCLE_TIME}_bucket[5m])))",
                "{{module}} on {{tier}}",
                unit="s",
                description="95th percentile of input + execution + output per module and tier.",
            ),
            Panel(
                "Standbys computing, per module",
                "sum by (namespace, module) (fogfleet_fallback_active)",
                "{{namespace}}/{{module}}",
                description="The workloads' own gauge: 1 per standby computing on board.",
            ),
        ),
    ),
    (
        "Operator",
        (
            Panel(
                "Reconciles per second",
                f"sum by (controller, result) (rate({RECONCILE_TOTAL}[5m]))",
                "{{controller}} {{result}}",
                unit="ops",
            ),
            Panel(
                "Reconcile time p95",
                f"histogram_quantile(0.95, sum by (le, controller) "
                f"(rate({RECONCILE_TIME}_bucket[5m])))",
                "{{controller}}",
                unit="s",
            ),
            Panel(
                "Reconcile errors per second",
                f"sum by (controller) (rate({RECONCILE_ERRORS}[5m]))",
                "{{controller}}",
                unit="ops",
            ),
            Panel(
                "Queue depth",
                f"sum by (name) ({WORKQUEUE_DEPTH})",
                "{{name}}",
                description="Fleets waiting for a reconcile (debounced, requeued or backing off).",
            ),
            Panel(
                "API writes per second",
                f"sum by (method, code) (rate({API_REQUESTS}{{{WRITES}}}[5m]))",
                "{{method}} {{code}}",
                unit="reqps",
                description="The operator's PATCH, POST, PUT and DELETE requests (kopf's own "
                "annotation patches are not counted).",
            ),
            Panel(
                "API requests per second",
                f"sum by (method) (rate({API_REQUESTS}[5m]))",
                "{{method}}",
                unit="reqps",
            ),
            Panel(
                "Watch restarts (1 h)",
                f"sum by (kind, reason) (increase({WATCH_RESTARTS}[1h]))",
                "{{kind}} {{reason}}",
            ),
            Panel(
                "Planning time p95",
                "histogram_quantile(0.95, sum by (le, scheduler) "
                "(rate(fogfleet_planning_seconds_bucket[30m])))",
                "{{scheduler}}",
                unit="s",
            ),
        ),
    ),
)

_FLEET = "{{ $labels.fleet_namespace }}/{{ $labels.fleet }}"
ALERTS: tuple[Alert, ...] = (
    Alert(
        "FogfleetFleetDegraded",
        f'{CONDITION}{{type="Degraded",status="True"}} == 1',
        f'{CONDITION}{{type="Degraded",status="True"}}',
        "10m",
        "A fleet has been Degraded for 10 minutes",
        f"RobotFleet {_FLEET} is Degraded: instances moving or stranded, a link lost or "
        "worse than declared, or the plan short of CPU. `kubectl describe robotfleet` says why.",
    ),
    Alert(
        "FogfleetFleetDrift",
        f'{CONDITION}{{type="Drift",status="True"}} == 1',
        f'{CONDITION}{{type="Drift",status="True"}}',
        "15m",
        "A fleet's modules miss more cycles than planned",
        f"RobotFleet {_FLEET} reports Drift: modules measured worse than the plan predicted "
        "(status.measured).",
    ),
    Alert(
        "FogfleetRobotLinkLost",
        f'{LINKS}{{state="Lost"}} > 0',
        f'{LINKS}{{state="Lost"}}',
        "1m",
        "A robot's link is lost",
        f"{{{{ $value }}}} robot(s) of RobotFleet {_FLEET} cannot be reached (status.links).",
        severity="critical",
    ),
    Alert(
        "FogfleetFallbacksActive",
        f"{FALLBACKS} > 0",
        FALLBACKS,
        "5m",
        "On-board fallbacks compute for unreachable remote modules",
        f"{{{{ $value }}}} standby(s) of RobotFleet {_FLEET} have computed on board for 5 minutes.",
    ),
    Alert(
        "FogfleetReconcileErrors",
        f"sum by (controller) (rate({RECONCILE_ERRORS}[5m])) > 0",
        f"sum by (controller) (rate({RECONCILE_ERRORS}[5m]))",
        "15m",
        "The fogfleet operator keeps failing to reconcile",
        "Controller {{ $labels.controller }} has failed reconciles for 15 minutes: see the "
        "operator's log and fogfleet_reconcile_errors_total by reason.",
    ),
)


def panels() -> list[Panel]:
    return [p for _, row in ROWS for p in row]


def _panel(p: Panel, pid: int, x: int, y: int) -> Json:
    return {
        "id": pid,
        "type": p.kind,
        "title": p.title,
        "description": p.description,
        "datasource": DATASOURCE,
        "gridPos": {"h": 8, "w": 12, "x": x, "y": y},
        "fieldConfig": {"defaults": {"unit": p.unit}, "overrides": []},
        "options": {"legend": {"displayMode": "list", "placement": "bottom", "showLegend": True}},
        "targets": [
            {"refId": "A", "datasource": DATASOURCE, "expr": p.expr, "legendFormat": p.legend}
        ],
    }


def dashboard() -> Json:
    """The dashboard model (Grafana's JSON): one row per ROWS entry, two panels a line."""
    out: list[Json] = []
    y, pid = 0, 1
    for title, row in ROWS:
        out.append(
            {
                "id": pid,
                "type": "row",
                "title": title,
                "collapsed": False,
                "gridPos": {"h": 1, "w": 24, "x": 0, "y": y},
                "panels": [],
            }
        )
        pid, y = pid + 1, y + 1
        for i, p in enumerate(row):
            out.append(_panel(p, pid, 12 * (i % 2), y + 8 * (i // 2)))
            pid += 1
        y += 8 * ((len(row) + 1) // 2)
    return {
        "uid": DASHBOARD_UID,
        "title": "fogfleet",
        "description": "Robot fleets placed by fogfleet: conditions, links, measured misses "
        "and the operator itself.",
        "tags": ["fogfleet", "kubernetes", "ros2"],
        "schemaVersion": SCHEMA_VERSION,
        "version": 1,
        "editable": True,
        "graphTooltip": 1,
        "time": {"from": "now-1h", "to": "now"},
        "refresh": "30s",
        "timezone": "browser",
        "annotations": {"list": []},
        "links": [],
        "templating": {
            "list": [
                {
                    "name": "datasource",
                    "label": "Data source",
                    "type": "datasource",
                    "query": "prometheus",
                    "current": {},
                    "hide": 0,
                }
            ]
        },
        "panels": out,
    }


def dashboard_json() -> str:
    """The chart's ``dashboards/fogfleet.json``: stable text (sorted keys, two-space indent)."""
    return json.dumps(dashboard(), indent=2, sort_keys=True) + "\n"


def alert_rules() -> list[Json]:
    """The PrometheusRule's groups (``spec.groups``)."""
    rules = [
        {
            "alert": a.name,
            "expr": a.expr,
            "for": a.for_,
            "labels": {"severity": a.severity},
            "annotations": {"summary": a.summary, "description": a.description},
        }
        for a in ALERTS
    ]
    return [{"name": "fogfleet", "rules": rules}]
