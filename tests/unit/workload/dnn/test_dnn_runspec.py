"""The split module's spec is read without pydantic, and every error names its key."""

from __future__ import annotations

import json

import pytest
from runspecs import SPEC, spec

from fogfleet.contract.dnnsplit import Spotlight
from fogfleet.workload.dnn.runspec import DnnRunSpec, action_names
from fogfleet.workload.spec import WorkloadSpec


def test_the_rendered_spec_reads_into_the_rules_model_in_seconds() -> None:
    run = DnnRunSpec.from_raw(SPEC)
    m = run.model
    assert m.spotlight is Spotlight.TIME and m.max_latency_s == pytest.approx(0.05)
    assert m.split_points[1].name == "bneck" and m.split_points[1].tensor_bytes == 6272
    assert m.split_points[0].head_s == pytest.approx(0.002) and m.max_robot_s is None
    assert (m.local_name, m.local_s, m.local_accuracy) == ("tiny", pytest.approx(4e-4), 0.61)
    assert action_names(m) == ["full offload", "b6", "bneck", "tiny"]
    assert run.planned_index == 2 and run.robot_factor == run.tail_factor == 1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"maxLatencyMillis": None}, "dnn.maxLatencyMillis: missing"),
        ({"robotFactor": None}, "dnn.robotFactor: missing"),
        ({"tailFactor": 0}, "dnn.tailFactor: 0 must be above 0"),
        ({"plannedAction": "b3"}, "dnn.plannedAction: 'b3' is not one of"),
        ({"spotlight": "speed"}, "dnn.spotlight: 'speed' is not one of time, cost, accuracy"),
        ({"accuracy": 1.5}, "dnn.accuracy: 1.5 is not a fraction"),
        ({"localModel": None}, "dnn.localModel: missing"),
        ({"splitPoints": [{"name": "b6", "headMillis": 2}]}, "dnn.splitPoints[0].tailMillis"),
        (
            {"splitPoints": [{"name": "b6", "headMillis": "x", "tailMillis": 1, "tensorBytes": 8}]},
            "dnn.splitPoints[0].headMillis: 'x' is not a number",
        ),
        (
            {"splitPoints": [{"name": "tiny", "headMillis": 1, "tailMillis": 1, "tensorBytes": 8}]},
            "dnn.splitPoints: names must differ",
        ),
    ],
)
def test_a_wrong_key_is_named(change: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError) as err:
        DnnRunSpec.from_raw(spec(**change))
    assert message in str(err.value)


def test_the_workload_spec_carries_dnn_only_when_the_key_is_there() -> None:
    env = {"FOGFLEET_MODULE_SPEC": json.dumps(SPEC), "FOGFLEET_ROLE": "head"}
    got = WorkloadSpec.from_env(env)
    assert got.dnn is not None and got.dnn.planned_action == "bneck"
    assert got.role.value == "head"
    plain = {k: v for k, v in SPEC.items() if k != "dnn"}
    assert WorkloadSpec.from_env({"FOGFLEET_MODULE_SPEC": json.dumps(plain)}).dnn is None


def test_the_workload_spec_names_a_wrong_dnn_key() -> None:
    env = {"FOGFLEET_MODULE_SPEC": json.dumps(spec(fullMillis=None))}
    with pytest.raises(ValueError, match=r"FOGFLEET_MODULE_SPEC: .*dnn\.fullMillis: missing"):
        WorkloadSpec.from_env(env)
