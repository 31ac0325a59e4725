"""ScalingSpec wire model: validation names the field; presets expand to tinyKube's settings."""

import pytest

from fogfleet.api.v1alpha1.scaling import (
    Backend,
    Mode,
    PolicyType,
    ScalingSpec,
    effective_min_replicas,
    load_scaling_spec,
    require_safe_minimum,
)
from fogfleet.autoscaling.behavior import (
    DEFAULT_BEHAVIOR,
    FAST_BEHAVIOR,
    TINYKUBE_BEHAVIOR,
    resolve_behavior,
)
from fogfleet.bench.autoscaling import POLICIES
from fogfleet.errors import InvalidSpec

TINYKUBE = {
    "maxReplicas": 36,
    "mode": "predictive",
    "slo": {"metric": "responseTime", "targetMillis": 350, "percentile": 99},
    "behavior": {"preset": "tinykube"},
    "pools": [
        {"tier": "edge", "maxReplicas": 17, "setupMillis": 1800},
        {"tier": "cloud", "maxReplicas": 19, "setupMillis": 4700, "sloTargetMillis": 500},
    ],
}


def error_field(data: dict[str, object]) -> str:
    with pytest.raises(InvalidSpec) as info:
        load_scaling_spec("SoftwareModule/detector", data)
    assert info.value.obj == "SoftwareModule/detector"
    return info.value.field


def test_tinykube_example_round_trips() -> None:
    spec = load_scaling_spec("SoftwareModule/detector", TINYKUBE)
    assert spec.mode is Mode.PREDICTIVE and spec.backend is Backend.FOGFLEET
    assert spec.wire()["pools"][1]["sloTargetMillis"] == 500
    assert ScalingSpec.model_validate(spec.wire()) == spec


def test_tinykube_preset_is_section_iv_c() -> None:
    behavior = resolve_behavior(load_scaling_spec("m", TINYKUBE))
    assert behavior == TINYKUBE_BEHAVIOR
    assert behavior.scale_up.stabilization_window_seconds == 60
    assert behavior.scale_up.policies[0].period_seconds == 30
    assert behavior.scale_down.stabilization_window_seconds == 300
    assert behavior.scale_down.policies[0].value == 50


def test_fast_preset_is_what_make_bench_measures_fogfleets_modes_with() -> None:
    spec = {"maxReplicas": 5, "behavior": {"preset": "fast"}}
    behavior = resolve_behavior(load_scaling_spec("m", spec))
    assert behavior == FAST_BEHAVIOR
    assert behavior.scale_up.stabilization_window_seconds == 0
    assert behavior.scale_down.stabilization_window_seconds == 30
    assert POLICIES["predictive"].behavior == POLICIES["reactive-slo"].behavior == FAST_BEHAVIOR


def test_explicit_direction_overrides_the_preset() -> None:
    data = {
        "maxReplicas": 5,
        "behavior": {
            "preset": "tinykube",
            "scaleDown": {"stabilizationWindowSeconds": 30},
        },
    }
    behavior = resolve_behavior(load_scaling_spec("m", data))
    assert behavior.scale_down.stabilization_window_seconds == 30
    assert behavior.scale_down.policies == TINYKUBE_BEHAVIOR.scale_down.policies
    assert behavior.scale_up == TINYKUBE_BEHAVIOR.scale_up


def test_no_behavior_means_the_hpa_defaults() -> None:
    assert resolve_behavior(load_scaling_spec("m", {"maxReplicas": 3})) == DEFAULT_BEHAVIOR


def test_policies_parse_hpa_names() -> None:
    data = {
        "maxReplicas": 5,
        "behavior": {
            "scaleUp": {
                "policies": [{"type": "Pods", "value": 4, "periodSeconds": 15}],
                "selectPolicy": "Min",
            }
        },
    }
    up = resolve_behavior(load_scaling_spec("m", data)).scale_up
    assert up.policies[0].type is PolicyType.PODS
    assert up.select_policy.value == "Min"


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"maxReplicas": 2, "minReplicas": 3}, "spec.scaling.minReplicas"),
        ({"maxReplicas": 2, "slo": {"targetMillis": 5}}, "spec.scaling.slo.metric"),
        (
            {"maxReplicas": 2, "slo": {"metric": "responseTime", "query": "up", "targetMillis": 5}},
            "spec.scaling.slo.metric",
        ),
        ({"maxReplicas": 2, "mode": "predictive"}, "spec.scaling.slo"),
        (
            {
                "maxReplicas": 2,
                "mode": "predictive",
                "backend": "hpa",
                "slo": {"metric": "responseTime", "targetMillis": 5},
            },
            "spec.scaling.backend",
        ),
        (
            {"maxReplicas": 20, "pools": [{"tier": "edge", "maxReplicas": 3}] * 2},
            "spec.scaling.pools[1].tier",
        ),
        (
            {"maxReplicas": 5, "pools": [{"tier": "cloud", "maxReplicas": 9}]},
            "spec.scaling.pools[0].maxReplicas",
        ),
        (
            {"maxReplicas": 5, "slo": {"metric": "latency", "targetMillis": 5}},
            "spec.scaling.slo.metric",
        ),
        (
            {
                "maxReplicas": 5,
                "slo": {"metric": "cycleTime", "targetMillis": 5, "percentile": 100},
            },
            "spec.scaling.slo.percentile",
        ),
        ({"maxReplicas": 5, "setupMillis": 1.8}, "spec.scaling.setupMillis"),
        ({"maxReplicas": 5, "behavior": {"preset": "slow"}}, "spec.scaling.behavior.preset"),
        ({"maxReplicas": 5, "extra": 1}, "spec.scaling.extra"),
        (
            {
                "maxReplicas": 5,
                "behavior": {
                    "scaleUp": {"policies": [{"type": "Pods", "value": 0, "periodSeconds": 15}]}
                },
            },
            "spec.scaling.behavior.scaleUp.policies[0].value",
        ),
    ],
)
def test_invalid_specs_name_the_field(data: dict[str, object], field: str) -> None:
    assert error_field(data) == field


def test_safety_helpers() -> None:
    spec = load_scaling_spec("m", {"maxReplicas": 4, "minReplicas": 0})
    assert effective_min_replicas(spec, safety_relevant=False) == 0
    assert effective_min_replicas(spec, safety_relevant=True) == 1
    require_safe_minimum(spec, obj="m", safety_relevant=False)
    with pytest.raises(InvalidSpec, match="at least 1 replica"):
        require_safe_minimum(spec, obj="SoftwareModule/m", safety_relevant=True)
    pooled = load_scaling_spec(
        "m",
        {
            "maxReplicas": 4,
            "minReplicas": 0,
            "pools": [{"tier": "edge", "maxReplicas": 2, "minReplicas": 1}],
        },
    )
    require_safe_minimum(pooled, obj="m", safety_relevant=True)


def test_edge_takes_private_traffic_by_default() -> None:
    spec = load_scaling_spec("m", TINYKUBE)
    assert [p.private_allowed for p in spec.pools or []] == [True, False]
