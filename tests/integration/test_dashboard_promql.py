"""Every panel's and alert's PromQL of the chart's dashboard and rules parses, by the real
Prometheus parser: ``promtool check rules`` (the promtool of the bed's tools, built by
``make cluster-tools``; skipped without it). Panels are checked as recording rules, the
alerts as the chart ships them. Whether they also return series is the e2e test's question
(e2e/tests/test_observability_queries.py)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from fogfleet.artefacts import dashboard as dash

CHART = Path(__file__).resolve().parents[2] / "charts" / "fogfleet"


def _promtool() -> str | None:
    try:
        from e2e.bed.base import load_versions
        from e2e.bed.tools import tool_specs

        binary = tool_specs(load_versions())["prometheus"].binaries["promtool"]
        if binary.is_file():
            return str(binary)
    except Exception:  # no bed tools here: a promtool on the PATH will do
        pass
    return shutil.which("promtool")


PROMTOOL = _promtool()
pytestmark = pytest.mark.skipif(PROMTOOL is None, reason="no promtool (make cluster-tools)")


def _check(path: Path) -> subprocess.CompletedProcess[str]:
    assert PROMTOOL is not None
    return subprocess.run(
        [PROMTOOL, "check", "rules", str(path)], capture_output=True, text=True, timeout=60
    )


def test_every_panel_expression_parses(tmp_path: Path) -> None:
    rules = [{"record": f"fogfleet:panel_{i}", "expr": p.expr} for i, p in enumerate(dash.panels())]
    path = tmp_path / "panels.yaml"
    path.write_text(yaml.safe_dump({"groups": [{"name": "panels", "rules": rules}]}))
    run = _check(path)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"SUCCESS: {len(rules)} rules found" in run.stdout


def test_the_charts_alert_rules_parse(tmp_path: Path) -> None:
    groups = yaml.safe_load((CHART / "dashboards" / "alerts.yaml").read_text())
    path = tmp_path / "alerts.yaml"
    path.write_text(yaml.safe_dump({"groups": groups}))
    run = _check(path)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"SUCCESS: {len(dash.ALERTS)} rules found" in run.stdout


def test_a_broken_expression_is_refused(tmp_path: Path) -> None:
    """The check can fail: a misspelt function is reported."""
    path = tmp_path / "broken.yaml"
    rules = [{"record": "x:y", "expr": "sum by (le (rat(fogfleet_plans_total[5m]))"}]
    path.write_text(yaml.safe_dump({"groups": [{"name": "b", "rules": rules}]}))
    assert _check(path).returncode != 0
