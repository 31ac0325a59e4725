"""The generated CRDs: committed copies match the models, schemas are structural and strict."""

from __future__ import annotations

import copy
import importlib.util
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import Field

from fogfleet.api.v1alpha1.base import FogModel, Quantity, parse_quantity
from fogfleet.api.v1alpha1.common import ObjectMeta
from fogfleet.artefacts import crds as crdgen
from fogfleet.artefacts.crds import (
    QUANTITY_PATTERN,
    CrdGenerationError,
    KindInfo,
    render_crd_text,
    render_crds,
    structural_schema,
)
from fogfleet.artefacts.files import check_crds, write_crds

REPO = Path(__file__).resolve().parents[3]
EXAMPLES = REPO / "manifests" / "examples"


def _load_checker() -> Any:
    # Loaded by path so it works whatever package layout tests/ gets.
    path = Path(__file__).parents[1] / "api" / "openapi_check.py"
    spec = importlib.util.spec_from_file_location("_fogfleet_openapi_check", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


validate = _load_checker().validate


def _schemas() -> dict[str, dict[str, Any]]:
    return {
        crd["spec"]["names"]["kind"]: crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]
        for crd in render_crds().values()
    }


def _nodes(schema: dict[str, Any], path: str = "") -> Iterator[tuple[str, dict[str, Any]]]:
    yield path or "<root>", schema
    for name, sub in schema.get("properties", {}).items():
        yield from _nodes(sub, f"{path}.{name}")
    if isinstance(schema.get("items"), dict):
        yield from _nodes(schema["items"], f"{path}[]")
    if isinstance(schema.get("additionalProperties"), dict):
        yield from _nodes(schema["additionalProperties"], f"{path}.*")


def _example_docs() -> list[dict[str, Any]]:
    docs = []
    for path in sorted(EXAMPLES.rglob("*.yaml")):
        docs.extend(d for d in yaml.safe_load_all(path.read_text()) if isinstance(d, dict))
    return [d for d in docs if str(d.get("apiVersion", "")).startswith("fogfleet.io/")]


def _module() -> dict[str, Any]:
    return next(copy.deepcopy(d) for d in _example_docs() if d["kind"] == "SoftwareModule")


# --- drift -------------------------------------------------------------------------------


def test_committed_crds_and_chart_copy_match_the_models() -> None:
    assert (REPO / "charts" / "fogfleet" / "Chart.yaml").is_file()
    assert check_crds(REPO / "crds") == []


def test_check_crds_reports_missing_changed_and_unexpected_files(tmp_path: Path) -> None:
    out = tmp_path / "crds"
    written = write_crds(out)
    assert sorted(p.name for p in written) == sorted(render_crds())
    assert check_crds(out) == []
    (out / "robotfleets.fogfleet.io.yaml").write_text("changed\n")
    (out / "computenodes.fogfleet.io.yaml").unlink()
    (out / "old.fogfleet.io.yaml").write_text("stale\n")
    problems = "\n".join(check_crds(out))
    assert "robotfleets.fogfleet.io.yaml: differs" in problems
    assert "computenodes.fogfleet.io.yaml: missing" in problems
    assert "old.fogfleet.io.yaml: no model generates it" in problems
    write_crds(out)
    assert check_crds(out) == []
    assert not (out / "old.fogfleet.io.yaml").exists()


def test_write_crds_also_writes_and_checks_the_chart_copy(tmp_path: Path) -> None:
    chart = tmp_path / "charts" / "fogfleet"
    chart.mkdir(parents=True)
    (chart / "Chart.yaml").write_text("name: fogfleet\n")
    written = write_crds(tmp_path / "crds")
    assert {p.parent.name for p in written} == {"crds", "dashboards"}
    assert len(written) == 2 * len(render_crds()) + 2  # and the dashboard and alerts
    templates = chart / "templates" / "crds"
    (templates / "softwaremodules.fogfleet.io.yaml").write_text("old\n")
    (chart / "dashboards" / "alerts.yaml").write_text("old\n")
    assert check_crds(tmp_path / "crds") == [
        f"{templates / 'softwaremodules.fogfleet.io.yaml'}: differs from the models "
        "(run `make crds`)",
        f"{chart / 'dashboards' / 'alerts.yaml'}: differs from the models (run `make crds`)",
    ]


def test_the_charts_crds_are_kept_templates_behind_a_value(tmp_path: Path) -> None:
    """Helm upgrades templates but never a chart's crds/ folder; keep survives uninstall."""
    chart = tmp_path / "charts" / "fogfleet"
    chart.mkdir(parents=True)
    (chart / "Chart.yaml").write_text("name: fogfleet\n")
    write_crds(tmp_path / "crds")
    for name, crd in render_crds().items():
        text = (chart / "templates" / "crds" / name).read_text()
        lines = [line for line in text.splitlines() if not line.startswith("#")]
        assert lines[0] == "{{- if .Values.crds.install }}" and lines[-1] == "{{- end }}"
        body = yaml.safe_load("\n".join(lines[1:-1]))
        assert body["metadata"]["annotations"] == {"helm.sh/resource-policy": "keep"}
        body["metadata"].pop("annotations")
        assert body == crd
    (chart / "crds").mkdir()
    (chart / "crds" / "robotfleets.fogfleet.io.yaml").write_text("old\n")
    assert any("templates now" in p for p in check_crds(tmp_path / "crds"))


def test_conditions_are_a_map_keyed_by_type() -> None:
    """Every long-lived kind (an ExplanationRequest is a question answered once: a phase)."""
    long_lived = {"computenodes", "softwaremodules", "robotfleets"}
    crds = [c for c in render_crds().values() if c["spec"]["names"]["plural"] in long_lived]
    assert len(crds) == len(long_lived)
    for crd in crds:
        schema = crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]
        conditions = schema["properties"]["status"]["properties"]["conditions"]
        assert conditions["x-kubernetes-list-type"] == "map"
        assert conditions["x-kubernetes-list-map-keys"] == ["type"]
        assert "type" in conditions["items"]["required"]
        assert "observedGeneration" in conditions["items"]["properties"]
        assert "observedGeneration" in schema["properties"]["status"]["properties"]


def test_rendering_is_deterministic_and_round_trips_through_yaml() -> None:
    first = {name: render_crd_text(crd) for name, crd in render_crds().items()}
    second = {name: render_crd_text(crd) for name, crd in render_crds().items()}
    assert first == second
    for name, text in first.items():
        assert yaml.safe_load(text) == render_crds()[name]


# --- shape of the CRDs --------------------------------------------------------------------


def test_names_scopes_versions_and_subresources() -> None:
    crds = {c["spec"]["names"]["kind"]: c for c in render_crds().values()}
    expected = {
        "ComputeNode": ("Cluster", ["cn"], "computenodes"),
        "SoftwareModule": ("Namespaced", ["swm"], "softwaremodules"),
        "RobotFleet": ("Namespaced", ["rf"], "robotfleets"),
        "ExplanationRequest": ("Namespaced", ["why"], "explanationrequests"),
    }
    assert set(crds) == set(expected)
    for kind, (scope, short, plural) in expected.items():
        spec = crds[kind]["spec"]
        assert crds[kind]["metadata"]["name"] == f"{plural}.fogfleet.io"
        assert spec["group"] == "fogfleet.io"
        assert spec["scope"] == scope
        assert spec["names"]["shortNames"] == short
        assert spec["names"]["categories"] == ["fogfleet"]
        (version,) = spec["versions"]
        assert (version["name"], version["served"], version["storage"]) == ("v1alpha1", True, True)
        assert version["subresources"] == {"status": {}}


def test_schemas_are_structural() -> None:
    int_or_string = [{"type": "integer"}, {"type": "string"}]
    for kind, schema in _schemas().items():
        assert schema["properties"]["metadata"] == {"type": "object"}, kind
        assert "nullable" not in schema["properties"]["spec"]
        assert "nullable" not in schema["properties"]["status"]
        for path, node in _nodes(schema):
            where = f"{kind}{path}"
            assert "type" in node or node.get("x-kubernetes-int-or-string"), where
            for banned in ("$ref", "$defs", "allOf", "oneOf", "not", "title", "default"):
                assert banned not in node, f"{where}: {banned}"
            assert "uniqueItems" not in node, where
            assert not isinstance(node.get("additionalProperties"), bool), where
            if "anyOf" in node:
                assert node["anyOf"] == int_or_string and node["x-kubernetes-int-or-string"]
                assert "type" not in node, where
            if node.get("type") == "array":
                assert "items" in node, where
            if node.get("type") == "object" and "properties" not in node and path != ".metadata":
                assert "additionalProperties" in node or node.get(
                    "x-kubernetes-preserve-unknown-fields"
                ), where


def test_quantities_are_int_or_string_with_the_quantity_pattern() -> None:
    cpu = _schemas()["SoftwareModule"]["properties"]["spec"]["properties"]["resources"]
    cpu = cpu["properties"]["cpu"]
    assert cpu["x-kubernetes-int-or-string"] is True
    assert cpu["pattern"] == QUANTITY_PATTERN
    assert cpu["minimum"] == 0


def test_plain_numbers_are_type_number_so_fractions_need_no_quotes() -> None:
    spec = _schemas()["SoftwareModule"]["properties"]["spec"]["properties"]
    cycle = spec["cycleTimeMillis"]
    assert cycle["type"] == "number" and cycle["minimum"] == 0
    assert "x-kubernetes-int-or-string" not in cycle
    row = spec["profile"]["items"]["properties"]
    assert row["meanMillis"]["type"] == row["stdMillis"]["type"] == "number"
    fleet = _schemas()["RobotFleet"]["properties"]["spec"]["properties"]
    weight = fleet["scheduler"]["properties"]["weights"]["items"]["properties"]["weight"]
    assert weight["type"] == "number"


@pytest.mark.parametrize(
    "text", ["0", "2", "+3", "500m", "1.5", ".5", "1.5Gi", "64Ki", "1e3", "2E-3", "4T"]
)
def test_quantity_pattern_accepts_what_the_models_accept(text: str) -> None:
    parse_quantity(text)
    assert re.search(QUANTITY_PATTERN, text)


@pytest.mark.parametrize("text", ["-1", "abc", "1.5 Gi", "1Gb", "", "1e", "--2", "m"])
def test_quantity_pattern_rejects_what_the_models_reject(text: str) -> None:
    with pytest.raises(ValueError):
        parse_quantity(text)
    assert not re.search(QUANTITY_PATTERN, text)


def test_optional_fields_are_nullable_except_enums() -> None:
    status = _schemas()["SoftwareModule"]["properties"]["status"]["properties"]
    assert status["observedGeneration"] == {
        "type": "integer",
        "nullable": True,
        "description": "The metadata.generation this status describes.",
    }
    # The API server would check a null against the enum and reject it: prune it instead.
    assert "nullable" not in status["offloadable"]
    assert None not in status["offloadable"]["enum"]


# --- the API server's view: samples against the schema --------------------------------------


def test_every_example_object_is_accepted_by_its_crd() -> None:
    schemas = _schemas()
    docs = _example_docs()
    assert len(docs) >= 20
    for doc in docs:
        assert validate(doc, schemas[doc["kind"]]) == [], doc["metadata"]["name"]


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (
            lambda d: d["spec"]["taxonomy"].update(realtime="firm"),
            "spec.taxonomy.realtime: 'firm' is not one of",
        ),
        (
            lambda d: d["spec"].update(cycleTimeMillis=-5),
            "spec.cycleTimeMillis: -5 is less than the minimum 0",
        ),
        (
            lambda d: d["spec"].update(cycleTimeMillis="-5"),
            "spec.cycleTimeMillis: must be of type number",
        ),
        (
            lambda d: d["spec"].update(cycleTimeMillis="fast"),
            "spec.cycleTimeMillis: must be of type number",
        ),
        (
            lambda d: d["spec"]["resources"].update(gpu=-1),
            "spec.resources.gpu: -1 is less than the minimum 0",
        ),
        (
            lambda d: d["spec"].update(activationPercent=101),
            "spec.activationPercent: 101 is more than the maximum 100",
        ),
        (
            lambda d: d["spec"].update(activationPercent="70"),
            "spec.activationPercent: must be of type integer",
        ),
        (lambda d: d["spec"].update(colour="blue"), "spec.colour: unknown field"),
        (lambda d: d["spec"]["profile"][0].update(cores=2), "spec.profile[0].cores: unknown field"),
        (
            lambda d: d["spec"].update(profiling={"mode": "sometimes"}),
            "spec.profiling.mode: 'sometimes'",
        ),
        (lambda d: d["spec"].update(profiling={"cycles": 2}), "spec.profiling.cycles: 2 is less"),
        (lambda d: d["spec"].pop("taxonomy"), "spec.taxonomy: required field is missing"),
        (lambda d: d["spec"]["template"].update(image=""), "spec.template.image: shorter than 1"),
    ],
)
def test_bad_software_module_is_rejected_by_the_schema(mutate: Any, expected: str) -> None:
    doc = _module()
    mutate(doc)
    errors = validate(doc, _schemas()["SoftwareModule"])
    assert any(e.startswith(expected) for e in errors), errors


def test_bad_fleet_and_node_values_are_rejected_by_the_schema() -> None:
    schemas = _schemas()
    fleet = next(copy.deepcopy(d) for d in _example_docs() if d["kind"] == "RobotFleet")
    fleet["spec"]["scheduler"] = {"algorithm": "genetic", "population": 2}
    errors = validate(fleet, schemas["RobotFleet"])
    assert any(e.startswith("spec.scheduler.algorithm: 'genetic'") for e in errors), errors
    assert any(e.startswith("spec.scheduler.population: 2 is less") for e in errors), errors
    node = next(copy.deepcopy(d) for d in _example_docs() if d["kind"] == "ComputeNode")
    node["spec"]["tier"] = "fog"
    node["spec"]["privacyLevel"] = -1
    errors = validate(node, schemas["ComputeNode"])
    assert any(e.startswith("spec.tier: 'fog'") for e in errors), errors
    assert any(e.startswith("spec.privacyLevel: -1") for e in errors), errors


def test_a_module_listed_twice_in_a_fleet_is_a_duplicate_key() -> None:
    fleet = next(copy.deepcopy(d) for d in _example_docs() if d["kind"] == "RobotFleet")
    fleet["spec"]["modules"].append({"name": fleet["spec"]["modules"][0]["name"]})
    k = len(fleet["spec"]["modules"]) - 1
    errors = validate(fleet, _schemas()["RobotFleet"])
    assert any(e.startswith(f"spec.modules[{k}]: duplicate value") for e in errors), errors


def test_null_is_kept_where_nullable_and_pruned_elsewhere() -> None:
    doc = _module()
    doc["spec"]["scope"] = None  # not nullable: the API server drops it, the default applies
    doc["status"] = {"offloadable": None, "observedGeneration": None}
    assert validate(doc, _schemas()["SoftwareModule"]) == []


def test_status_written_by_the_operator_fits_the_schema() -> None:
    status = {
        "observedGeneration": 3,
        "conditions": [
            {"type": "Ready", "status": "True", "reason": "Planned", "message": "",
             "lastTransitionTime": "2025-01-01T00:00:00Z", "observedGeneration": 3},
        ],
        "scheduler": "nsga2",
        "placement": [{"robot": "r1", "module": "m", "node": "edge-1", "tier": "edge", "cpu": "2"}],
        "objectives": [{"name": "missRate", "value": 0.01}],
        "predictedMissRate": 0.01,
        "modulesPlaced": 40,
        "split": "16/24/0",
    }  # fmt: skip
    fleet = next(copy.deepcopy(d) for d in _example_docs() if d["kind"] == "RobotFleet")
    fleet["status"] = status
    assert validate(fleet, _schemas()["RobotFleet"]) == []
    status["conditions"][0]["status"] = "Maybe"
    assert validate(fleet, _schemas()["RobotFleet"])


# --- printer columns and CEL ----------------------------------------------------------------


def _field_at(schema: dict[str, Any], json_path: str) -> dict[str, Any]:
    node = schema
    for part in re.sub(r"\[\?\(@\.\w+==\"\w+\"\)\]", "[]", json_path).strip(".").split("."):
        name, _, filtered = part.partition("[]")
        node = node["properties"][name]
        if part.endswith("[]") or (filtered == "" and part != name):
            node = node["items"]
    return node


def test_printer_columns_point_to_real_fields_of_the_right_type() -> None:
    kinds = {"string": {"string"}, "integer": {"integer"}, "number": {"number", "integer"}}
    for crd in render_crds().values():
        version = crd["spec"]["versions"][0]
        schema = version["schema"]["openAPIV3Schema"]
        for column in version["additionalPrinterColumns"]:
            if column["jsonPath"] == ".metadata.creationTimestamp":
                assert column["type"] == "date"
                continue
            target = _field_at(schema, column["jsonPath"])
            if target.get("x-kubernetes-int-or-string"):
                assert column["type"] == "string", column
            elif target["type"] == "array":  # kubectl prints a list as JSON: ["a","b"]
                assert column["type"] == "string", column
                assert target["items"]["type"] == "string", column
            else:
                assert target["type"] in kinds[column["type"]], column
    fleet = render_crds()["robotfleets.fogfleet.io.yaml"]["spec"]["versions"][0]
    names = [c["name"] for c in fleet["additionalPrinterColumns"]]
    assert names[:4] == ["Ready", "Placed", "Split", "Miss"] and names[-1] == "Age"
    miss = next(c for c in fleet["additionalPrinterColumns"] if c["name"] == "Miss")
    # a percentage as the CLI prints it (domain.miss_rates), not the fraction
    assert (miss["type"], miss["jsonPath"]) == ("string", ".status.predictedMiss")


def _rules(schema: dict[str, Any]) -> Iterator[tuple[str, dict[str, Any], dict[str, Any]]]:
    for path, node in _nodes(schema):
        for rule in node.get("x-kubernetes-validations", []):
            yield path, node, rule


def test_cel_rules_name_only_fields_of_their_node() -> None:
    count = 0
    for kind, schema in _schemas().items():
        for path, node, rule in _rules(schema):
            count += 1
            assert rule["message"], (kind, path)
            for chain, call in re.findall(r"self((?:\.\w+)+)(\()?", rule["rule"]):
                names = chain.strip(".").split(".")
                target = node
                for name in names[:-1] if call else names:
                    assert name in target.get("properties", {}), (kind, path, rule["rule"], name)
                    target = target["properties"][name]
    assert count >= 5


def test_cross_field_rules_of_the_models_are_cel_rules() -> None:
    schemas = _schemas()
    fleet_rules = [
        r["rule"] for r in schemas["RobotFleet"]["properties"]["spec"]["x-kubernetes-validations"]
    ]
    assert any("robotSelector" in r for r in fleet_rules)
    objectives = schemas["RobotFleet"]["properties"]["spec"]["properties"]["scheduler"][
        "properties"
    ]["objectives"]
    assert objectives["maxItems"] == len(objectives["items"]["enum"])
    modules = schemas["RobotFleet"]["properties"]["spec"]["properties"]["modules"]
    assert modules["x-kubernetes-list-type"] == "map"
    assert modules["x-kubernetes-list-map-keys"] == ["name"]
    assert "name" in modules["items"]["required"]
    cycle = schemas["SoftwareModule"]["properties"]["spec"]["properties"]["cycleTimeMillis"]
    assert cycle["x-kubernetes-validations"][0]["rule"] == "self > 0.0"


# --- the generator is generic ---------------------------------------------------------------


class _Scaling(FogModel):
    min_replicas: int = Field(default=1, ge=1)
    max_replicas: int = Field(default=3, ge=1)
    target: Quantity | None = None


class _Spec(FogModel):
    scaling: _Scaling | None = None
    tags: set[str] = Field(default_factory=set)
    ratio: float = Field(default=0.5, gt=0, lt=1)


class _Status(FogModel):
    observed_generation: int | None = None


class _Thing(FogModel):
    metadata: ObjectMeta
    spec: _Spec
    status: _Status | None = None


def _thing_info(model: type[FogModel] = _Thing) -> KindInfo:
    return KindInfo(
        model=model, kind="Thing", plural="things", singular="thing", scope="Namespaced",
        short_names=(), columns=(),
    )  # fmt: skip


def test_a_new_nested_spec_with_min_and_max_gets_a_cel_rule() -> None:
    spec = structural_schema(_thing_info())["properties"]["spec"]
    scaling = spec["properties"]["scaling"]
    assert scaling["nullable"] is True
    assert scaling["x-kubernetes-validations"] == [
        {
            "rule": "!has(self.minReplicas) || !has(self.maxReplicas) || "
            "self.minReplicas <= self.maxReplicas",
            "message": "minReplicas must not exceed maxReplicas",
        }
    ]
    assert scaling["properties"]["target"]["x-kubernetes-int-or-string"] is True
    assert scaling["properties"]["target"]["nullable"] is True
    assert spec["properties"]["tags"]["x-kubernetes-list-type"] == "set"
    ratio = spec["properties"]["ratio"]
    assert ratio == {
        "type": "number", "minimum": 0, "exclusiveMinimum": True,
        "maximum": 1, "exclusiveMaximum": True,
    }  # fmt: skip


def test_a_field_without_a_structural_form_is_refused_by_name() -> None:
    class _Union(FogModel):
        choice: int | list[str]

    class _BadThing(FogModel):
        metadata: ObjectMeta
        spec: _Union
        status: _Status | None = None

    with pytest.raises(CrdGenerationError, match=r"spec\.choice: a union of 2 types"):
        structural_schema(_thing_info(_BadThing))


def test_rules_for_a_missing_path_fail_loudly() -> None:
    info = crdgen.KINDS[0]
    broken = KindInfo(
        **{**info.__dict__, "rules": {"spec.noSuchField": ({"rule": "true", "message": "x"},)}}
    )
    with pytest.raises(CrdGenerationError, match=r"spec\.noSuchField"):
        structural_schema(broken)


# --- documentation (kubectl explain) -----------------------------------------------------------


def test_every_field_of_every_kind_is_documented() -> None:
    """kubectl explain prints each field's description: none may be missing or empty (the
    scalar items of a list or map are described by the list or map itself; metadata is the
    API server's, which refuses anything but its type there)."""
    undocumented = [
        f"{kind}{path}"
        for kind, schema in _schemas().items()
        for path, node in _nodes(schema)
        if not str(node.get("description", "")).strip()
        and not (path.endswith(("[]", ".*")) and node.get("type") != "object")
        and path != ".metadata"
    ]
    assert undocumented == []


def test_descriptions_are_one_line_and_state_their_defaults() -> None:
    schemas = _schemas()
    scheduler = schemas["RobotFleet"]["properties"]["spec"]["properties"]["scheduler"]
    population = scheduler["properties"]["population"]["description"]
    assert population == "NSGA-II population size. Default: 100."
    assert "Default: missRate, missedCycles" in scheduler["properties"]["objectives"]["description"]
    ros = schemas["RobotFleet"]["properties"]["spec"]["properties"]["ros"]["properties"]
    assert ros["enabled"]["description"].endswith("Default: true.")
    for kind, schema in schemas.items():
        for path, node in _nodes(schema):
            assert "\n" not in node.get("description", ""), f"{kind}{path}"
