"""The v1alpha1 models and the loader: examples load; errors name object, field and reason."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.loader import load_paths, parse_object
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.build import build_problem
from fogfleet.errors import DanglingReference, InvalidSpec

REPO = Path(__file__).resolve().parents[3]
WAREHOUSE = REPO / "manifests" / "examples" / "warehouse"
SINGLE = REPO / "manifests" / "examples" / "single-robot"


def _docs(path: Path) -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all(path.read_text()) if isinstance(d, dict)]


def _module() -> dict[str, Any]:
    return copy.deepcopy(_docs(WAREHOUSE / "modules.yaml")[0])


def _fleet() -> dict[str, Any]:
    return copy.deepcopy(_docs(WAREHOUSE / "fleet.yaml")[0])


def _node() -> dict[str, Any]:
    return copy.deepcopy(_docs(WAREHOUSE / "nodes.yaml")[0])


def _invalid(doc: dict[str, Any]) -> InvalidSpec:
    with pytest.raises(InvalidSpec) as info:
        parse_object(doc)
    return info.value


# --- the examples -------------------------------------------------------------------------


def test_warehouse_example_loads_and_builds_a_problem() -> None:
    catalog = load_paths([WAREHOUSE])
    assert len(catalog.nodes) == 11
    assert len(catalog.modules) == 8
    (fleet,) = catalog.fleets
    assert sum(n.spec.tier.value == "robot" for n in catalog.nodes.values()) == 5
    problem = build_problem(fleet, catalog)
    assert problem.n_instances >= 5 * 7
    assert problem.n_nodes == 11


def test_single_robot_example_loads_on_its_own() -> None:
    catalog = load_paths([SINGLE])
    (fleet,) = catalog.fleets
    assert fleet.metadata.name == "single-robot"
    problem = build_problem(fleet, catalog)
    assert problem.n_nodes == 2


def test_every_example_object_round_trips_through_its_wire_form() -> None:
    kinds: dict[str, Any] = {
        "ComputeNode": ComputeNode,
        "SoftwareModule": SoftwareModule,
        "RobotFleet": RobotFleet,
    }
    count = 0
    for path in sorted((REPO / "manifests" / "examples").rglob("*.yaml")):
        for doc in _docs(path):
            if doc.get("kind") not in kinds:
                continue
            obj = parse_object(doc)
            again = kinds[doc["kind"]].model_validate(obj.wire())
            assert again == obj
            count += 1
    assert count >= 23


def test_fractional_millis_rates_and_weights_need_no_quotes() -> None:
    module = _module()
    module["spec"]["cycleTimeMillis"] = 33.3
    module["spec"]["profile"][0].update(meanMillis=12.5, stdMillis=0.4)
    module["spec"]["topics"]["publishes"][0]["rateHz"] = 7.5
    mod = parse_object(module)
    assert isinstance(mod, SoftwareModule)
    assert mod.spec.cycle_time_millis == 33.3 and mod.spec.profile[0].std_millis == 0.4
    fleet = _fleet()
    fleet["spec"]["scheduler"] = {
        "choice": "weighted",
        "weights": [{"objective": "missRate", "weight": 0.5}],
    }
    assert isinstance(parse_object(fleet), RobotFleet)
    node = _node()
    node["spec"]["network"][0]["latencyMillis"] = 0.3
    assert isinstance(parse_object(node), ComputeNode)


def test_other_kinds_are_ignored_not_rejected() -> None:
    catalog = load_paths([WAREHOUSE / "00-namespace.yaml"])
    assert [str(s) for s in catalog.ignored] == ["Namespace/warehouse"]


# --- errors name the object, the field and the reason ---------------------------------------

Mutation = Callable[[dict[str, Any]], object]


@pytest.mark.parametrize(
    ("mutate", "field", "reason"),
    [
        (lambda d: d["spec"].update(colour="blue"), "spec.colour", "unknown field"),
        (
            lambda d: d["spec"]["profile"][1].update(cores=2),
            "spec.profile[1].cores",
            "unknown field",
        ),
        (
            lambda d: d["spec"].update(activationPercent="often"),
            "spec.activationPercent",
            "valid integer",
        ),
        (lambda d: d["spec"].update(template="nginx"), "spec.template", "valid dictionary"),
        (
            lambda d: d["spec"]["taxonomy"].update(realtime="firm"),
            "spec.taxonomy.realtime",
            "'hard', 'soft' or 'none'",
        ),
        (lambda d: d["spec"].update(scope="everywhere"), "spec.scope", "'perRobot' or 'shared'"),
        (
            lambda d: d["spec"].update(cycleTimeMillis=-5),
            "spec.cycleTimeMillis",
            "zero or more, not -5",
        ),
        (
            lambda d: d["spec"].update(cycleTimeMillis="-5"),
            "spec.cycleTimeMillis",
            "written without quotes",
        ),
        (
            lambda d: d["spec"].update(cycleTimeMillis=0),
            "spec.cycleTimeMillis",
            "greater than zero",
        ),
        (
            lambda d: d["spec"]["profile"][0].update(meanMillis=0),
            "spec.profile[0].meanMillis",
            "greater than zero",
        ),
        (
            lambda d: d["spec"]["resources"].update(gpu=-1),
            "spec.resources.gpu",
            "greater than or equal to 0",
        ),
        (lambda d: d["spec"].pop("taxonomy"), "spec.taxonomy", "required field is missing"),
    ],
)
def test_bad_software_module_names_object_and_field(
    mutate: Mutation, field: str, reason: str
) -> None:
    doc = _module()
    mutate(doc)
    err = _invalid(doc)
    assert err.obj == "SoftwareModule/nav-motion-planning"
    assert err.field == field
    assert reason in err.message
    assert str(err).startswith(f"SoftwareModule/nav-motion-planning: {field}: ")


def test_shared_hard_realtime_module_is_rejected_with_the_scope_field() -> None:
    doc = _module()
    doc["spec"]["scope"] = "shared"
    doc["spec"]["taxonomy"]["realtime"] = "hard"
    err = _invalid(doc)
    assert (err.field, err.message) == (
        "spec.scope",
        "a hard real-time or safety-critical module must be perRobot (it runs on board)",
    )


def test_fleet_without_robots_names_the_robots_field() -> None:
    doc = _fleet()
    doc["spec"].pop("robots", None)
    doc["spec"].pop("robotSelector", None)
    err = _invalid(doc)
    assert err.obj == f"RobotFleet/{doc['metadata']['name']}"
    assert err.field == "spec.robots"
    assert "robotSelector" in err.message


def test_fleet_with_a_bad_scheduler_enum_names_the_field() -> None:
    doc = _fleet()
    doc["spec"]["scheduler"] = {"algorithm": "genetic"}
    err = _invalid(doc)
    assert err.field == "spec.scheduler.algorithm"
    assert "'nsga2'" in err.message


def test_a_cpu_limit_below_the_planned_cpu_names_the_field() -> None:
    doc = _fleet()
    doc["spec"]["scheduler"] = {"cpuLimitPercent": 50}
    err = _invalid(doc)
    assert err.field == "spec.scheduler.cpuLimitPercent"
    assert "greater than or equal to 100" in err.message
    doc["spec"]["scheduler"] = {"cpuLimitPercent": 100}
    fleet = parse_object(doc)
    assert isinstance(fleet, RobotFleet) and fleet.spec.scheduler.cpu_limit_percent == 100


def test_node_with_a_bad_tier_names_the_field() -> None:
    doc = _node()
    doc["spec"]["tier"] = "fog"
    err = _invalid(doc)
    assert err.obj == f"ComputeNode/{doc['metadata']['name']}"
    assert err.field == "spec.tier"
    assert "'robot', 'edge' or 'cloud'" in err.message


def test_wrong_api_version_and_unknown_kind_are_named() -> None:
    doc = _module()
    doc["apiVersion"] = "fogfleet.io/v1"
    assert _invalid(doc).field == "apiVersion"
    doc = _module()
    doc["kind"] = "SoftwarePackage"
    err = _invalid(doc)
    assert (err.obj, err.field) == ("SoftwarePackage/nav-motion-planning", "kind")


def test_loader_names_the_file_for_broken_yaml(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("kind: [unclosed\n")
    with pytest.raises(InvalidSpec, match="not valid YAML") as info:
        load_paths([path])
    assert info.value.obj == str(path)


def test_missing_path_is_reported() -> None:
    with pytest.raises(InvalidSpec, match="no such file or directory"):
        load_paths([REPO / "no-such-folder"])


# --- references are checked when the problem is built ---------------------------------------


def _write(tmp_path: Path, docs: list[dict[str, Any]]) -> Path:
    path = tmp_path / "objects.yaml"
    path.write_text(yaml.safe_dump_all(docs))
    return path


def test_dangling_module_reference_names_the_list_entry(tmp_path: Path) -> None:
    fleet = _fleet()
    fleet["spec"]["modules"].append({"name": "no-such-module"})
    k = len(fleet["spec"]["modules"]) - 1
    others = [d for d in _docs(WAREHOUSE / "nodes.yaml") + _docs(WAREHOUSE / "modules.yaml")]
    catalog = load_paths([_write(tmp_path, [*others, fleet])])
    with pytest.raises(DanglingReference) as info:
        build_problem(catalog.fleets[0], catalog)
    err = info.value
    assert err.obj == f"RobotFleet/{fleet['metadata']['name']}"
    assert err.field == f"spec.modules[{k}].name"
    assert "no-such-module" in err.message and "does not exist" in err.message


def test_dangling_robot_reference_names_the_list_entry(tmp_path: Path) -> None:
    fleet = _fleet()
    fleet["spec"]["robots"] = ["ghost-robot"]
    fleet["spec"].pop("robotSelector", None)
    others = _docs(WAREHOUSE / "nodes.yaml") + _docs(WAREHOUSE / "modules.yaml")
    catalog = load_paths([_write(tmp_path, [*others, fleet])])
    with pytest.raises(DanglingReference) as info:
        build_problem(catalog.fleets[0], catalog)
    assert info.value.field == "spec.robots[0]"
    assert "ghost-robot" in info.value.message


def test_every_cross_field_rule_is_stated_once_and_reaches_its_crd() -> None:
    """The models' RULES are what the CRDs validate with (one statement, two checkers)."""
    from fogfleet.api.v1alpha1.computenode import ComputeNodeSpec
    from fogfleet.api.v1alpha1.fallback import Fallback
    from fogfleet.api.v1alpha1.robotfleet import RobotFleetSpec, SchedulerSettings
    from fogfleet.api.v1alpha1.softwaremodule import SoftwareModuleSpec
    from fogfleet.artefacts.crds import render_crds

    crds = {c["spec"]["names"]["kind"]: c for c in render_crds().values()}

    def validations(kind: str, *path: str) -> list[dict[str, str]]:
        node = crds[kind]["spec"]["versions"][0]["schema"]["openAPIV3Schema"]
        for part in path:
            node = node["properties"][part]
        return list(node.get("x-kubernetes-validations", []))

    for kind, path, model in [
        ("ComputeNode", ("spec",), ComputeNodeSpec),
        ("SoftwareModule", ("spec",), SoftwareModuleSpec),
        ("RobotFleet", ("spec",), RobotFleetSpec),
        ("RobotFleet", ("spec", "scheduler", "objectives"), SchedulerSettings),
        ("SoftwareModule", ("spec", "fallback"), Fallback),
        ("RobotFleet", ("spec", "fallback"), Fallback),
    ]:
        for rule in model.RULES:
            assert rule.crd() in validations(kind, *path), (kind, rule.message)


# --- fallback (issue 13) -------------------------------------------------------------------


def test_fallback_onboard_on_a_shared_module_names_the_field() -> None:
    doc = _module()
    doc["spec"]["scope"] = "shared"
    doc["spec"]["fallback"] = {"mode": "onboard"}
    err = _invalid(doc)
    assert err.field == "spec.fallback.mode"
    assert "a shared module has none" in err.message


def test_fallback_onboard_without_outputs_names_the_field() -> None:
    doc = _module()
    doc["spec"]["topics"] = {"subscribes": doc["spec"]["topics"]["subscribes"]}
    doc["spec"]["fallback"] = {"mode": "onboard"}
    err = _invalid(doc)
    assert (err.field, err.message.split(":")[0]) == (
        "spec.fallback.mode",
        "onboard and variant need topics.publishes",
    )


@pytest.mark.parametrize(
    ("fallback", "field", "why"),
    [
        ({"mode": "variant"}, "spec.fallback.variant", "mode variant needs the name"),
        ({"mode": "onboard", "variant": "lite"}, "spec.fallback.variant", "only with mode variant"),
        ({"variant": "lite"}, "spec.fallback.variant", "only with mode variant"),
        ({"mode": "variant", "variant": "Not_A_Name"}, "spec.fallback.variant", ""),
    ],
)
def test_fallback_variant_needs_its_module_and_only_with_its_mode(
    fallback: dict[str, Any], field: str, why: str
) -> None:
    doc = _module()
    doc["spec"]["fallback"] = fallback
    err = _invalid(doc)
    assert err.field == field and why in err.message


def test_a_fleet_default_fallback_cannot_be_a_variant() -> None:
    from fogfleet.api.v1alpha1.robotfleet import RobotFleetSpec

    with pytest.raises(ValueError, match="set it on that SoftwareModule"):
        RobotFleetSpec.model_validate(
            {
                "robots": ["r1"],
                "modules": [{"name": "m"}],
                "fallback": {"mode": "variant", "variant": "lite"},
            }
        )


@pytest.mark.parametrize(
    ("fallback", "field"),
    [
        ({"mode": "cloud"}, "spec.fallback.mode"),
        ({"silentCycles": 0}, "spec.fallback.silentCycles"),
    ],
)
def test_bad_fallback_values_name_their_field(fallback: dict[str, Any], field: str) -> None:
    doc = _module()
    doc["spec"]["fallback"] = fallback
    assert _invalid(doc).field == field


def test_the_module_fallback_wins_over_the_fleets_and_only_eligible_modules_keep_one() -> None:
    from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
    from fogfleet.domain.fallback import effective_fallback

    catalog = load_paths([WAREHOUSE])
    (fleet,) = catalog.fleets
    default = Fallback(mode=FallbackMode.ONBOARD, silent_cycles=5)
    spec = fleet.spec.model_copy(update={"fallback": default})
    mods = {m.metadata.name: m.spec for m in catalog.modules.values()}
    hpe = mods["human-pose-estimation"]
    got = effective_fallback(hpe, spec)
    assert got is not None and got.silent_cycles == 5  # the fleet's default
    assert effective_fallback(hpe, fleet.spec) is None  # fleets default to none
    own = hpe.model_copy(update={"fallback": Fallback(mode=FallbackMode.NONE)})
    assert effective_fallback(own, spec) is None  # the module's own mode wins
    windows = hpe.model_copy(update={"fallback": Fallback(step_back_cycles=40)})
    got = effective_fallback(windows, spec)  # mode from the fleet, windows its own
    assert got is not None and (got.silent_cycles, got.step_back_cycles) == (3, 40)
    # a module that must run on board never runs elsewhere: nothing to fall back from
    critical = [m for m in mods.values() if m.taxonomy.safety.value == "critical"]
    assert critical and all(effective_fallback(m, spec) is None for m in critical)


def test_a_status_part_is_read_back_as_its_model_or_none_with_a_warning(caplog) -> None:
    from fogfleet.api.v1alpha1.base import status_part
    from fogfleet.api.v1alpha1.profiling import ProfilingStatus

    good = {"status": {"profiling": {"runs": [], "rows": []}}}
    assert status_part(good, "profiling", ProfilingStatus) == ProfilingStatus()
    assert status_part({}, "profiling", ProfilingStatus) is None
    assert status_part({"status": None}, "profiling", ProfilingStatus) is None
    bad = {"status": {"profiling": {"runs": "not a list"}}}
    assert status_part(bad, "profiling", ProfilingStatus) is None
    assert "unreadable status.profiling" in caplog.text


def test_a_managed_cluster_is_never_a_robot_and_has_no_node_name_of_its_own() -> None:
    robot = _node()
    robot["spec"]["managedCluster"] = "cloud"
    err = _invalid(robot)
    assert "managedCluster" in f"{err.field} {err.message}", err
    cloud = _node()
    cloud["spec"] = {"tier": "cloud", "hardwareType": "vm", "managedCluster": "cloud",
                     "nodeName": "cloud-vm-1"}  # fmt: skip
    err = _invalid(cloud)
    assert "nodeName" in f"{err.field} {err.message}", err
    del cloud["spec"]["nodeName"]
    assert isinstance(parse_object(cloud), ComputeNode)
    cloud["spec"]["managedCluster"] = "Not_A_Name"
    assert "managedCluster" in _invalid(cloud).field
