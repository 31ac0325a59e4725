"""`fogfleet simulate --model FILE`: plans simulated under a fitted execution model."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fogfleet.commandline.cli import main

WAREHOUSE = Path(__file__).resolve().parents[4] / "manifests" / "examples" / "warehouse"
MODULE = "human-pose-estimation"
TYPES = ("robot-nuc", "dsv3-16", "fsv2-8", "default")
ARGV = ["simulate", str(WAREHOUSE), "--duration", "20", "--generations", "10", "--json"]


def _model(tmp_path: Path, doc: object) -> str:
    path = tmp_path / "model.json"
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.integration
def test_a_fitted_model_slows_the_module_it_measured(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    slower = [
        {"module": MODULE, "hardwareType": hw, "factor": 1.5, "noiseMillis": 0, "cycles": 1000}
        for hw in TYPES
    ]
    model = _model(tmp_path, {"spread": 0.3, "corrections": slower})
    assert main([*ARGV, "--model", model]) == 0
    fitted = json.loads(capsys.readouterr()[0])["nsga2"]["modules"]
    assert main(ARGV) == 0
    declared = json.loads(capsys.readouterr()[0])["nsga2"]["modules"]
    assert fitted[MODULE] > declared[MODULE] + 0.1


def test_a_malformed_model_is_refused_with_the_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*ARGV, "--model", _model(tmp_path, {"corrections": []})]) == 2
    assert (
        "model.json: execution model: missing or malformed field 'spread'"
        in (capsys.readouterr()[1])
    )
    assert main([*ARGV, "--model", _model(tmp_path, {"spread": 2})]) == 2
    assert "spread must lie in [0, 1], got 2.0" in capsys.readouterr()[1]
    assert main([*ARGV, "--model", str(tmp_path / "none.json")]) == 2
    assert "none.json: No such file or directory" in capsys.readouterr()[1]
    both = [*ARGV, "--model", "m.json", "--from-prometheus", "http://127.0.0.1:9"]
    assert main(both) == 2
    assert "give --model or --from-prometheus, not both" in capsys.readouterr()[1]
