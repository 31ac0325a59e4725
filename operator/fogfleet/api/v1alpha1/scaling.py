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
from fogfleet.api.v1alpha1.common import Tier
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
    "effective_min_replicas",
    "load_scaling_spec",
    "require_safe_minimum",
]


class PolicyType(StrEnum):
    """How a scaling policy counts: whole pods or a percentage of the current replicas."""

    PODS = "Pods"
    PERCENT = "Percent"


class SelectPolicy(StrEnum):
    """Which policy wins when several apply (HPA semantics)."""

    MAX = "Max"
    MIN = "Min"
    DISABLED = "Disabled"


PoolTier = Literal[Tier.EDGE, Tier.CLOUD]
"""The tiers a shared service's replicas run in (never a robot's own computer)."""


class SloMetric(StrEnum):
    """Histograms of the metrics contract an SLO can name (fogfleet.contract.metrics)."""

    RESPONSE_TIME = "responseTime"
    CYCLE_TIME = "cycleTime"


class _FieldError(ValueError):
    """A cross-field error that knows which field to blame (read by load_scaling_spec)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


class Mode(StrEnum):
    """reactive (follow the metric, like the HPA) or predictive (size replicas for the SLO
    with tinyKube's queueing forecast)."""

    REACTIVE = "reactive"
    PREDICTIVE = "predictive"


class Backend(StrEnum):
    """Who moves the replicas: fogfleet itself, or a rendered HPA / KEDA ScaledObject."""

    FOGFLEET = "fogfleet"
    HPA = "hpa"
    KEDA = "keda"


class ScalingPolicySpec(FogModel):
    """One HPA scaling policy: change by at most value (Pods or Percent) per period."""

    type: PolicyType
    """Pods or Percent."""
    value: PosInt
    """How many pods, or what percent of the current replicas."""
    period_seconds: Annotated[int, Field(ge=1, le=1800)]
    """The window the limit applies to, in seconds."""


class ScalingRulesSpec(FogModel):
    """One direction of the HPA ``behavior``; unset fields take the HPA's defaults."""

    stabilization_window_seconds: Annotated[int, Field(ge=0, le=3600)] | None = None
    """Past recommendations considered, in seconds (HPA: 0 up, 300 down)."""
    policies: Annotated[list[ScalingPolicySpec], Field(min_length=1)] | None = None
    """Limits on the rate of change."""
    select_policy: SelectPolicy | None = None
    """Max, Min or Disabled: which policy applies when several do."""


class BehaviorSpec(FogModel):
    """HPA ``behavior`` semantics; a preset fills the directions left unset."""

    preset: Literal["tinykube", "fast"] | None = None
    """tinykube: tinyKube's rules (IV-C; +100 %/30 s after a 60 s window, -50 %/60 s after 5
    min). fast: the rules `make bench` measures fogfleet's reactive-slo and predictive modes
    with (up at once, down by half after 30 s)."""
    scale_up: ScalingRulesSpec | None = None
    """Rules when adding replicas."""
    scale_down: ScalingRulesSpec | None = None
    """Rules when removing replicas."""


class SloSpec(FogModel):
    """A latency SLO: a contract metric or a raw PromQL query (in seconds), and its target."""

    metric: SloMetric | None = None
    """A metric of the metrics contract (set this or query)."""
    query: Annotated[str, Field(min_length=1)] | None = None
    """A PromQL query returning seconds (set this or metric)."""
    target_millis: PosInt
    """The SLO target, in milliseconds."""
    percentile: Annotated[int, Field(ge=1, le=99)] = 95
    """Which percentile of the metric must meet the target (1-99)."""

    @model_validator(mode="after")
    def _metric_xor_query(self) -> SloSpec:
        if (self.metric is None) == (self.query is None):
            raise _FieldError(
                "metric", "set exactly one of metric (from the metrics contract) or query"
            )
        return self


class PoolSpec(FogModel):
    """The replicas of one tier. Unset fields inherit from the ScalingSpec."""

    tier: PoolTier
    """edge or cloud."""
    max_replicas: PosInt
    """Most replicas in this tier."""
    min_replicas: NonNegInt | None = None
    """Fewest replicas in this tier (default: the module's minReplicas)."""
    slo_target_millis: PosInt | None = None
    """The SLO target in this tier, in milliseconds (default: slo.targetMillis)."""
    setup_millis: NonNegInt | None = None
    """Time for a new replica to become ready, in milliseconds (tinyKube: 1800 edge, 4700
    cloud)."""
    accepts_private: bool | None = None
    """Whether private requests may go to this tier (default: edge only)."""

    @property
    def private_allowed(self) -> bool:
        """Private traffic goes to the edge only, unless the spec says otherwise."""
        if self.accepts_private is None:
            return self.tier is Tier.EDGE
        return self.accepts_private


class ScalingSpec(FogModel):
    """SLO-driven autoscaling of a shared module (tinyKube III-B, IV-C)."""

    min_replicas: NonNegInt = 1
    """Fewest replicas (safety-relevant modules keep at least 1)."""
    max_replicas: PosInt
    """Most replicas."""
    slo: SloSpec | None = None
    """The latency SLO the replicas are sized for (or set targetCpuUtilizationPercent)."""
    target_cpu_utilization_percent: Annotated[int, Field(ge=1, le=100)] | None = None
    """Scale on CPU use instead of an SLO, in percent of the request."""
    behavior: BehaviorSpec | None = None
    """How fast replicas change (HPA behavior semantics)."""
    mode: Mode = Mode.REACTIVE
    """reactive or predictive."""
    setup_millis: NonNegInt | None = None
    """Time for a new replica to become ready, in milliseconds (predictive mode)."""
    pools: list[PoolSpec] | None = None
    """Replicas per tier (edge first, then cloud); default: one pool over any tier."""
    backend: Backend = Backend.FOGFLEET
    """Who scales: fogfleet itself, or a rendered HPA or KEDA ScaledObject."""

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
        seen: set[Tier] = set()
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
