"""``fogfleet plan`` and ``fogfleet explain`` on a split network (issue 48): the action RoboEC2's
rule takes with each instance's tail where the plan puts it, why, and why not the others."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from tests.unit.splitfleet import DNN, HPE, split_catalog

from fogfleet.commandline.cli import main

FAST = ["--population", "8", "--generations", "2", "--seed", "1"]


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """The split warehouse written out as a user's folder."""
    catalog = split_catalog(DNN)
    objects = [*catalog.nodes.values(), *catalog.modules.values(), *catalog.fleets]
    docs = [o.model_dump(by_alias=True, exclude_none=True, mode="json") for o in objects]
    (tmp_path / "site.yaml").write_text(yaml.safe_dump_all(docs))
    return tmp_path


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> Any:
    assert main(list(argv)) == 0
    return json.loads(capsys.readouterr().out)


def test_plan_says_each_split_instances_action_and_why(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = _json(capsys, "plan", str(folder), "--json", *FAST)
    rows = [r for r in doc["placement"] if r["module"] == HPE]
    assert len(rows) == 5
    for r in rows:
        split = r["split"]
        if r["tier"] == "robot":  # nothing else left there: the local model alone
            assert split["action"] == "tiny"
        else:  # 120 Mbit/s wifi: the whole network off board is fastest (domain tests)
            assert split["action"] == "full offload"
            assert "over 120 Mbit/s" in split["reason"] and "minAccuracy 0.8" in split["reason"]
    assert all("split" not in r for r in doc["placement"] if r["module"] != HPE)


def test_explain_shows_the_other_actions_and_why_not(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = _json(
        capsys, "explain", str(folder), "--module", HPE, "--robot", "robot-1", "-o", "json", *FAST
    )
    (inst,) = doc["instances"]
    split = inst["split"]
    assert split["action"] == "full offload"
    others = {a["action"]: a["reason"] for a in split["alternatives"]}
    assert set(others) == {"b6", "bneck", "tiny"}
    assert others["tiny"] == "accuracy 0.61 < minAccuracy 0.8"
    assert others["bneck"].startswith("time: full offload is better (")
