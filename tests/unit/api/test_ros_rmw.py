"""spec.ros.rmwImplementation: only an RMW the discovery-server isolation works with."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.loader import parse_object
from fogfleet.artefacts.crds import render_crds
from fogfleet.errors import InvalidSpec

REPO = Path(__file__).resolve().parents[3]
FLEET = yaml.safe_load((REPO / "manifests" / "examples" / "warehouse" / "fleet.yaml").read_text())


def _fleet(**ros: Any) -> dict[str, Any]:
    doc = copy.deepcopy(FLEET)
    doc["spec"]["ros"] = ros
    return doc


def test_cyclone_with_discovery_servers_is_refused_naming_the_field_and_what_works() -> None:
    with pytest.raises(InvalidSpec) as info:
        parse_object(_fleet(rmwImplementation="rmw_cyclonedds_cpp"))
    assert info.value.obj == "RobotFleet/warehouse"
    assert info.value.field == "spec.ros.rmwImplementation"
    assert "rmw_fastrtps_cpp" in info.value.message and "ignore" in info.value.message


def test_fast_dds_is_accepted_and_any_rmw_without_the_wiring() -> None:
    assert parse_object(_fleet(rmwImplementation="rmw_fastrtps_cpp"))
    assert parse_object(_fleet())
    off = parse_object(_fleet(enabled=False, rmwImplementation="rmw_cyclonedds_cpp"))
    assert off.spec.ros.rmw_implementation == "rmw_cyclonedds_cpp"  # type: ignore[union-attr]


def test_the_crd_says_the_same_rule() -> None:
    crd = render_crds()["robotfleets.fogfleet.io.yaml"]
    schema = crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]
    ros = schema["properties"]["spec"]["properties"]["ros"]
    (rule,) = ros["x-kubernetes-validations"]
    assert "rmw_fastrtps_cpp" in rule["rule"] and "has(self.enabled)" in rule["rule"]
    assert rule["message"].startswith("rmwImplementation: ")
