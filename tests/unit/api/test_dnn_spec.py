"""``SoftwareModule.spec.dnn`` (issue 48): a split network's fields, validated with messages
that name the field and the reason, and the rules it keeps with the rest of the spec."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.dnn import Spotlight
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.dnnpairs import model_of
from fogfleet.errors import InvalidSpec

MODULES = (
    Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse" / "modules.yaml"
)
HPE = "human-pose-estimation"
DNN: dict[str, Any] = {
    "inputBytes": "588Ki",
    "outputBytes": 4000,
    "accuracy": 0.92,
    "fullMillis": 3.8,
    "splitPoints": [{"name": "bneck", "headMillis": 2, "tailMillis": 1.2, "tensorBytes": 6272}],
    "localModel": {"name": "tiny", "robotMillis": 0.4, "accuracy": 0.61},
}


PROFILE: dict[str, Any] = {  # what a profiling Job measured on one hardware type
    "hardwareType": "jetson",
    "inputBytes": 150528,
    "outputBytes": 4000,
    "fullMillis": 7.9,
    "localMillis": 0.9,
    "splitPoints": [{"name": "bneck", "headMillis": 4.6, "tailMillis": 2.9, "tensorBytes": 6272}],
}


def _split_module() -> dict[str, Any]:
    """The warehouse's pose estimator as a split network (no profile, no fallback)."""
    doc = next(d for d in yaml.safe_load_all(MODULES.read_text()) if d["metadata"]["name"] == HPE)
    doc["spec"].pop("profile")
    doc["spec"].pop("fallback", None)
    doc["spec"]["dnn"] = copy.deepcopy(DNN)
    return doc


def test_a_split_network_loads_and_reads_in_seconds_with_alpha_from_the_cycle() -> None:
    module = parse_object(_split_module())
    assert isinstance(module, SoftwareModule) and module.spec.dnn is not None
    model = model_of(module.spec.dnn, module.spec.cycle_seconds)
    assert model.spotlight is Spotlight.TIME  # the default
    assert model.max_latency_s == pytest.approx(0.1)  # cycleTimeMillis 100
    assert model.input_bytes == 588 * 1024
    assert model.split_points[0].head_s == pytest.approx(2e-3)
    assert model.local_s == pytest.approx(0.4e-3)


def _unmeasured(spec: dict[str, Any]) -> None:
    """``spec.dnn`` without what profiling measures, and profiling on."""
    dnn = spec["dnn"]
    for key in ("inputBytes", "outputBytes", "fullMillis"):
        dnn.pop(key)
    dnn["localModel"].pop("robotMillis")
    dnn["splitPoints"] = [{"name": p["name"]} for p in dnn["splitPoints"]]
    spec["profiling"] = {"mode": "auto"}


def test_with_profiling_auto_a_split_network_declares_no_time_and_may_declare_profiles() -> None:
    doc = _split_module()
    _unmeasured(doc["spec"])
    module = parse_object(doc)
    assert isinstance(module, SoftwareModule) and module.spec.dnn is not None
    assert module.spec.dnn.declared() == []
    assert "splitPoints[0].tailMillis" in module.spec.dnn.missing()
    doc["spec"]["dnn"]["profiles"] = [PROFILE]
    module = parse_object(doc)
    assert isinstance(module, SoftwareModule) and module.spec.dnn is not None
    assert module.spec.dnn.profiles[0].split_points[0].tensor_bytes == 6272


Mutation = Callable[[dict[str, Any]], object]


@pytest.mark.parametrize(
    ("mutate", "field", "reason"),
    [
        (lambda s: s["dnn"].update(spotlight="speed"), "spec.dnn.spotlight", "'time', 'cost'"),
        (lambda s: s["dnn"].update(accuracy=1.5), "spec.dnn.accuracy", "less than or equal to 1"),
        (lambda s: s["dnn"].pop("localModel"), "spec.dnn.localModel", "required field"),
        (
            lambda s: s["dnn"].update(fullMillis=0),
            "spec.dnn.fullMillis",
            "must be greater than zero",
        ),
        (
            lambda s: s["dnn"]["splitPoints"].append(dict(s["dnn"]["splitPoints"][0])),
            "spec.dnn.splitPoints",
            "bneck listed more than once",
        ),
        (
            lambda s: s["dnn"]["splitPoints"][0].update(tensorBytes=0),
            "spec.dnn.splitPoints[0].tensorBytes",
            "must be greater than zero",
        ),
        (
            lambda s: s["dnn"]["localModel"].update(name="bneck"),
            "spec.dnn.localModel.name",
            "'bneck' is also a split point's name",
        ),
        (
            lambda s: s["dnn"].update(maxLatencyMillis=150),
            "spec.dnn.maxLatencyMillis",
            "at most cycleTimeMillis",
        ),
        (lambda s: s.update(scope="shared"), "spec.dnn", "must be perRobot"),
        (
            lambda s: s["taxonomy"].update(realtime="hard"),
            "spec.dnn",
            "a hard real-time or safety-critical module stays whole",
        ),
        (
            lambda s: s.update(profile=[{"hardwareType": "default", "cpu": 1, "meanMillis": 9}]),
            "spec.profile",
            "a dnn module's times are dnn's",
        ),
        (
            lambda s: s.update(fallback={"mode": "onboard"}),
            "spec.fallback",
            "falls back to dnn.localModel",
        ),
        (lambda s: s.update(profiling={"mode": "auto"}), "spec.dnn", "leave them out"),
        (lambda s: s["dnn"].pop("fullMillis"), "spec.dnn", "unless profiling.mode is auto"),
        (
            lambda s: s["dnn"]["splitPoints"][0].pop("tailMillis"),
            "spec.dnn",
            "every split point's headMillis, tailMillis",
        ),
        (
            lambda s: s["dnn"].update(profiles=[dict(PROFILE, splitPoints=[])]),
            "spec.dnn.profiles[0].splitPoints",
            "are not splitPoints' names in order",
        ),
        (
            lambda s: s["dnn"].update(profiles=[PROFILE, PROFILE]),
            "spec.dnn.profiles",
            "listed more than once",
        ),
    ],
)
def test_a_bad_split_network_names_its_field_and_reason(
    mutate: Mutation, field: str, reason: str
) -> None:
    doc = _split_module()
    mutate(doc["spec"])
    with pytest.raises(InvalidSpec) as info:
        parse_object(doc)
    assert info.value.field == field, str(info.value)
    assert reason in info.value.message, str(info.value)


def test_kubectl_explain_explains_every_dnn_field() -> None:
    from fogfleet.artefacts.crds import render_crds

    crd = next(c for c in render_crds().values() if c["spec"]["names"]["kind"] == "SoftwareModule")
    dnn = crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["spec"][
        "properties"
    ]["dnn"]
    assert "RoboEC2" in dnn["description"]
    fields = dnn["properties"]
    assert set(fields) >= {"spotlight", "maxLatencyMillis", "minAccuracy", "maxRobotMillis",
                           "inputBytes", "outputBytes", "accuracy", "fullMillis", "splitPoints",
                           "localModel"}  # fmt: skip
    assert all(f.get("description") for f in fields.values())
    assert fields["spotlight"]["enum"] == ["time", "cost", "accuracy"]
