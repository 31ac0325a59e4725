"""The chart's Grafana dashboard, read by Grafana's own schema types (grafana-foundation-sdk).

``Dashboard.from_json`` keeps only what the dashboard schema defines, so writing the model back
and comparing it with the file finds every key Grafana would not know (a misspelt ``gridPos``,
a panel field of another version) and every value the schema would change. Runs in its own
venv (``make dashboard-check``), like checkov: the SDK is not a dependency of fogfleet.

    python tests/dashboard/check_dashboard.py charts/fogfleet/dashboards/fogfleet.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from grafana_foundation_sdk.cog.encoder import JSONEncoder
from grafana_foundation_sdk.models.dashboard import Dashboard


def differences(ours: Any, schema: Any, path: str = "") -> list[str]:
    """Where ``schema`` (the SDK's round trip) lost or changed what ``ours`` says."""
    if isinstance(ours, dict):
        if not isinstance(schema, dict):
            return [f"{path or '/'}: not an object in the schema"]
        out = [f"{path}/{k}: not in the dashboard schema" for k in ours if k not in schema]
        for k, v in ours.items():
            if k in schema:
                out += differences(v, schema[k], f"{path}/{k}")
        return out
    if isinstance(ours, list):
        if not isinstance(schema, list) or len(ours) != len(schema):
            return [f"{path}: list changed by the schema"]
        return [
            d
            for i, (a, b) in enumerate(zip(ours, schema, strict=True))
            for d in differences(a, b, f"{path}[{i}]")
        ]
    return [] if ours == schema else [f"{path}: {ours!r} read as {schema!r}"]


def main(paths: list[str]) -> int:
    bad = 0
    for name in paths:
        ours = json.loads(Path(name).read_text())
        schema = json.loads(json.dumps(Dashboard.from_json(ours), cls=JSONEncoder))
        found = differences(ours, schema)
        for line in found:
            print(f"{name}: {line}", file=sys.stderr)
        bad += len(found)
        print(
            f"{name}: {len(ours.get('panels', []))} panels, "
            f"{'matches' if not found else 'does not match'} Grafana's dashboard schema"
        )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
