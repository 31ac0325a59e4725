"""`fogfleet simulate --from-prometheus`: plans simulated with measured execution times."""

from __future__ import annotations

import json
import threading
import urllib.parse
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from fogfleet.api.loader import load_paths
from fogfleet.commandline.cli import main
from fogfleet.controllers.measure.observed import declared_rows
from fogfleet.domain.observed import declared_row

WAREHOUSE = Path(__file__).resolve().parents[4] / "manifests" / "examples" / "warehouse"
MODULE = "human-pose-estimation"
SLOWER = 1.5
COUNT = 10000.0


def _series() -> list[tuple[dict[str, str], float, float]]:
    """(labels, count, mean s): the module 1.5x slower than declared at 1 CPU everywhere."""
    catalog = load_paths([WAREHOUSE])
    module = next(m for (_, n), m in catalog.modules.items() if n == MODULE)
    hardware = {n.spec.hardware_type: n for n in catalog.nodes.values()}
    raw = module.model_dump(by_alias=True, mode="json", exclude_none=True)
    out = []
    for hw, rows in declared_rows(raw, hardware).items():
        row = declared_row(rows, 1.0)
        assert row is not None
        labels = {"module": MODULE, "hardware_type": hw, "cpu": "1000m"}
        out.append((labels, COUNT, SLOWER * row.mean))
    return out


@pytest.fixture
def prometheus() -> Iterator[str]:
    series = _series()

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            query = urllib.parse.parse_qs(urllib.parse.urlparse(self.path).query)["query"][0]
            assert 'namespace="warehouse"' in query, query
            result: list[dict[str, Any]] = []
            for labels, n, mean in series:
                if "_count" in query:
                    value = n
                elif "_sum" in query:
                    value = n * mean
                else:  # the 95th percentile
                    value = 1.2 * mean
                result.append({"metric": labels, "value": [0, str(value)]})
            body = json.dumps(
                {"status": "success", "data": {"resultType": "vector", "result": result}}
            ).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *_: Any) -> None:
            return

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.integration
def test_measured_times_show_what_the_declared_plan_misses_and_what_a_re_plan_gains(
    prometheus: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["simulate", str(WAREHOUSE), "--duration", "20", "--generations", "10"]
    code = main([*argv, "--from-prometheus", prometheus, "--json"])
    out, _ = capsys.readouterr()
    assert code == 0
    doc = json.loads(out)
    assert set(doc) == {"nsga2", "nsga2 re-planned"}
    code = main([*argv, "--json"])
    declared = json.loads(capsys.readouterr()[0])
    # as declared it missed little; 1.5x slower, the same plan misses far more ...
    assert doc["nsga2"]["modules"][MODULE] > declared["nsga2"]["modules"][MODULE] + 0.1
    # ... and a plan made from the measured times misses less than that plan in reality
    assert doc["nsga2 re-planned"]["modules"][MODULE] < doc["nsga2"]["modules"][MODULE]
    # the table says where the times come from
    code = main([*argv, "--from-prometheus", prometheus])
    text = capsys.readouterr()[0]
    assert code == 0 and f"{MODULE} on " in text and "x1.50" in text
    assert "nsga2 re-planned" in text
