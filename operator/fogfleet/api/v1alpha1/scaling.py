"""``SoftwareModule.spec.scaling``: bounds, SLO and behaviour of a shared service's replicas.

Example (the tinyKube setting of seeds/tinykube-cloud-edge-resource-management.txt, Table I
and section IV-C)::

    scaling:
      minReplicas: 1
      maxReplicas: 36
      mode: predictive
      slo: {metric: responseTime, targetMillis: 350, percentile: 99}
      behavior: {preset: tinykube}
      pools:
        - {tier: edge, maxReplicas: 17, setupMillis: 1800}
        - {tier: cloud, maxReplicas: 19, setupMillis: 4700, sloTargetMillis: 500}

Times are integers with their unit in the name; tinyKube's 1.8 s setup is ``setupMillis: 1800``
(an int cannot say 1.8 seconds, so the brief's ``setupSeconds`` became ``setupMillis``).
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, model_validator

from fogfleet.api.v1alpha1.base import FogModel, NonNegInt, PosInt
from fogfleet.autoscaling import behavior as engine
from fogfleet.autoscaling.contract import SloMetric
from fogfleet.errors import InvalidSpec

__all__ = [
    "Backend",
    "BehaviorSpec",
    "Mode",
    "PolicyType",
    "PoolSpec",
    "ScalingPolicySpec",
    "ScalingRulesSpec",
    "ScalingSpec",
    "SelectPolicy",
    "SloMetric",
    "SloSpec",
    "TierName",
    "effective_min_replicas",
    "load_scaling_spec",
    "require_safe_minimum",
]

PolicyType = engine.PolicyType
SelectPolicy = engine.SelectPolicy


class _FieldError(ValueError):
    """A cross-field error that knows which field to blame (read by load_scaling_spec)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


class Mode(StrEnum):
    REACTIVE = "reactive"
    PREDICTIVE = "predictive"


class Backend(StrEnum):
    """Who moves the replicas: fogfleet itself, or a rendered HPA / KEDA ScaledObject."""

    FOGFLEET = "fogfleet"
    HPA = "hpa"
    KEDA = "keda"


class TierName(StrEnum):
    EDGE = "edge"
    CLOUD = "cloud"


class ScalingPolicySpec(FogModel):
    type: engine.PolicyType
    value: PosInt
    period_seconds: Annotated[int, Field(ge=1, le=1800)]


class ScalingRulesSpec(FogModel):
    """One direction of the HPA ``behavior``; unset fields take the HPA's defaults."""

    stabilization_window_seconds: Annotated[int, Field(ge=0, le=3600)] | None = None
    policies: Annotated[list[ScalingPolicySpec], Field(min_length=1)] | None = None
    select_policy: engine.SelectPolicy | None = None

    def resolve(self, default: engine.ScalingRules) -> engine.ScalingRules:
        return engine.ScalingRules(
            default.stabilization_window_seconds
            if self.stabilization_window_seconds is None
            else self.stabilization_window_seconds,
            default.policies
            if self.policies is None
            else tuple(
                engine.ScalingPolicy(p.type, p.value, p.period_seconds) for p in self.policies
            ),
            default.select_policy if self.select_policy is None else self.select_policy,
        )


class BehaviorSpec(FogModel):
    """HPA ``behavior`` semantics; ``preset: tinykube`` fills the directions left unset."""

    preset: Literal["tinykube"] | None = None
    scale_up: ScalingRulesSpec | None = None
    scale_down: ScalingRulesSpec | None = None

    def resolve(self) -> engine.Behavior:
        """The engine's :class:`~fogfleet.autoscaling.behavior.Behavior` for this spec."""
        base = engine.TINYKUBE_BEHAVIOR if self.preset == "tinykube" else engine.DEFAULT_BEHAVIOR
        up = self.scale_up.resolve(base.scale_up) if self.scale_up else base.scale_up
        down = self.scale_down.resolve(base.scale_down) if self.scale_down else base.scale_down
        return engine.Behavior(up, down)


class SloSpec(FogModel):
    """A latency SLO: a contract metric or a raw PromQL query (in seconds), and its target."""

    metric: SloMetric | None = None
    query: Annotated[str, Field(min_length=1)] | None = None
    target_millis: PosInt
    percentile: Annotated[int, Field(ge=1, le=99)] = 95

    @model_validator(mode="after")
    def _metric_xor_query(self) -> SloSpec:
        if (self.metric is None) == (self.query is None):
            raise _FieldError(
                "metric", "set exactly one of metric (from the metrics contract) or query"
            )
        return self


class PoolSpec(FogModel):
    """The replicas of one tier. Unset fields inherit from the ScalingSpec."""

    tier: TierName
    max_replicas: PosInt
    min_replicas: NonNegInt | None = None
    slo_target_millis: PosInt | None = None
    setup_millis: NonNegInt | None = None
    accepts_private: bool | None = None

    @property
    def private_allowed(self) -> bool:
        """Private traffic goes to the edge only, unless the spec says otherwise."""
        if self.accepts_private is None:
            return self.tier is TierName.EDGE
        return self.accepts_private


class ScalingSpec(FogModel):
    min_replicas: NonNegInt = 1
    max_replicas: PosInt
    slo: SloSpec | None = None
    target_cpu_utilization_percent: Annotated[int, Field(ge=1, le=100)] | None = None
    behavior: BehaviorSpec | None = None
    mode: Mode = Mode.REACTIVE
    setup_millis: NonNegInt | None = None
    pools: list[PoolSpec] | None = None
    backend: Backend = Backend.FOGFLEET

    @model_validator(mode="after")
    def _consistent(self) -> ScalingSpec:
        if self.min_replicas > self.max_replicas:
            raise _FieldError(
                "minReplicas",
                f"{self.min_replicas} must not exceed maxReplicas ({self.max_replicas})",
            )
        if self.mode is Mode.PREDICTIVE:
            if self.slo is None:
                raise _FieldError("slo", "mode predictive needs an slo to size the replicas for")
            if self.backend is not Backend.FOGFLEET:
                raise _FieldError(
                    "backend",
                    f"mode predictive needs backend fogfleet ({self.backend.value} can only "
                    "react to a metric)",
                )
        if self.slo is not None and self.target_cpu_utilization_percent is not None:
            raise _FieldError(
                "targetCpuUtilizationPercent", "set either slo or targetCpuUtilizationPercent"
            )
        seen: set[TierName] = set()
        for i, pool in enumerate(self.pools or []):
            if pool.tier in seen:
                raise _FieldError(f"pools[{i}].tier", f"{pool.tier.value} appears twice")
            seen.add(pool.tier)
            if pool.max_replicas > self.max_replicas:
                raise _FieldError(
                    f"pools[{i}].maxReplicas",
                    f"{pool.max_replicas} exceeds the module's maxReplicas ({self.max_replicas})",
                )
            low = self.min_replicas if pool.min_replicas is None else pool.min_replicas
            if low > pool.max_replicas:
                raise _FieldError(
                    f"pools[{i}].minReplicas", f"{low} exceeds maxReplicas ({pool.max_replicas})"
                )
        return self

    def resolved_behavior(self) -> engine.Behavior:
        return (self.behavior or BehaviorSpec()).resolve()


def effective_min_replicas(spec: ScalingSpec, *, safety_relevant: bool) -> int:
    """The floor the scaler enforces: a safety-relevant service never scales to zero."""
    return max(spec.min_replicas, 1 if safety_relevant else 0)


def require_safe_minimum(spec: ScalingSpec, *, obj: str, safety_relevant: bool) -> None:
    """Raise :class:`InvalidSpec` when a safety-relevant service could scale to zero replicas."""
    if not safety_relevant:
        return
    if spec.pools:
        floors = [
            spec.min_replicas if p.min_replicas is None else p.min_replicas for p in spec.pools
        ]
    else:
        floors = [spec.min_replicas]
    if sum(floors) < 1:
        raise InvalidSpec(
            obj,
            "spec.scaling.minReplicas",
            "a safety-relevant module must keep at least 1 replica",
        )


def load_scaling_spec(
    obj: str, data: Mapping[str, Any], *, field: str = "spec.scaling"
) -> ScalingSpec:
    """Validate ``data`` into a :class:`ScalingSpec`; errors name the first offending field."""
    try:
        return ScalingSpec.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        parts = [f"[{p}]" if isinstance(p, int) else f".{p}" for p in first["loc"]]
        message = str(first["msg"]).removeprefix("Value error, ")
        cause = first.get("ctx", {}).get("error")
        if isinstance(cause, _FieldError):
            parts.append(f".{cause.field}")
            message = cause.message
        raise InvalidSpec(obj, field + "".join(parts), message) from exc
