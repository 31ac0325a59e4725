"""``domain.checks``: the rules a fleet must meet before it is built; the build stops at the
first broken one, ``fleet_errors`` lists them all."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.checks import fleet_errors
from fogfleet.errors import InvalidSpec

LITE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse-lite"


def test_a_valid_fleet_has_no_errors() -> None:
    catalog = load_paths([LITE])
    assert fleet_errors(catalog.fleets[0], catalog) == []


def test_the_build_stops_at_the_first_error_fleet_errors_lists(tmp_path: Path) -> None:
    docs = [d for f in sorted(LITE.glob("*.yaml")) for d in yaml.safe_load_all(f.read_text())]
    nodes = [d for d in docs if d and d["kind"] == "ComputeNode"]
    [fleet] = [d for d in docs if d and d["kind"] == "RobotFleet"]
    for node in nodes[:2]:
        del node["spec"]["capacity"]
    for ref in fleet["spec"]["modules"][:2]:
        ref["overrides"] = {"cycleTimeMillis": 0}
    fleet["spec"]["robots"].append("ghost")
    (tmp_path / "all.yaml").write_text(yaml.safe_dump_all([d for d in docs if d]))
    catalog = load_paths([tmp_path])
    errors = fleet_errors(catalog.fleets[0], catalog)
    assert [e.field for e in errors] == [
        f"spec.robots[{len(fleet['spec']['robots']) - 1}]",
        "spec.capacity",
        "spec.capacity",
        "spec.modules[0].overrides.cycleTimeMillis",
        "spec.modules[1].overrides.cycleTimeMillis",
    ]
    with pytest.raises(InvalidSpec) as info:
        build_problem(catalog.fleets[0], catalog)
    assert str(info.value) == str(errors[0])
