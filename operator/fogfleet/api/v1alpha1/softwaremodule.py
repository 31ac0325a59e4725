"""SoftwareModule (namespaced): one containerised ROS 2 module of the robot software stack.

The taxonomy follows multi-robot-edge-cloud-scheduling III-A (Fig. 2): execution pattern,
real-time class and safety class. ``cycleTimeMillis`` and ``activationPercent`` are Table II's
"max. cycle time" and "avg. execution rate"; ``profile`` is the look-up table of Fig. 3
(execution time per hardware type and CPU limit).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import Field, model_validator

from .base import FogModel, NonNegInt, PosInt, Quantity, parse_quantity
from .common import Condition, Name, ObjectMeta, Tier
from .computenode import DeviceType
from .scaling import ScalingSpec

__all__ = [
    "ContainerTemplate",
    "ExecutionPattern",
    "ProfileEntry",
    "RealtimeClass",
    "Requirements",
    "SafetyClass",
    "Scope",
    "SoftwareModule",
    "SoftwareModuleSpec",
    "SoftwareModuleStatus",
    "Taxonomy",
    "Topic",
    "Topics",
]


class ExecutionPattern(StrEnum):
    CONTINUOUS = "continuous"
    PERIODIC = "periodic"
    EVENT = "event"


class RealtimeClass(StrEnum):
    HARD = "hard"
    SOFT = "soft"
    NONE = "none"


class SafetyClass(StrEnum):
    CRITICAL = "critical"
    RELEVANT = "relevant"
    IRRELEVANT = "irrelevant"


class Scope(StrEnum):
    """perRobot: one instance on or for every robot. shared: replicas that serve the fleet."""

    PER_ROBOT = "perRobot"
    SHARED = "shared"


class Taxonomy(FogModel):
    execution_pattern: ExecutionPattern
    realtime: RealtimeClass
    safety: SafetyClass


class EnvVar(FogModel):
    name: Annotated[str, Field(min_length=1)]
    value: str = ""


# Environment fogfleet owns in every module container (the ROS wiring and FOGFLEET_*).
RESERVED_ENV_PREFIXES = ("FOGFLEET_", "ROS_", "RMW_", "FASTDDS_", "FASTRTPS_")


class ContainerTemplate(FogModel):
    image: Annotated[str, Field(min_length=1)]
    image_pull_policy: Literal["Always", "IfNotPresent", "Never"] | None = None
    command: list[str] = Field(default_factory=list)
    args: list[str] = Field(default_factory=list)
    env: list[EnvVar] = Field(default_factory=list)
    metrics_port: Annotated[int, Field(ge=1, le=65535)] | None = Field(
        default=None,
        description=(
            "Port on which the module serves the metrics contract (/metrics) and /healthz: "
            "fogfleet then adds the port, liveness and readiness probes and Prometheus "
            "scrape annotations. The ROS 2 workload image serves 9100."
        ),
    )

    @model_validator(mode="after")
    def _owned_env(self) -> ContainerTemplate:
        for k, e in enumerate(self.env):
            if e.name.startswith(RESERVED_ENV_PREFIXES):
                raise ValueError(
                    f"env[{k}].name: {e.name} is set by fogfleet (the ROS 2 wiring and "
                    f"FOGFLEET_* variables: {', '.join(RESERVED_ENV_PREFIXES)}); configure it "
                    "in the RobotFleet's spec.ros instead"
                )
        return self


class ModuleResources(FogModel):
    """The module's nominal request: what a plain Deployment would ask kube-scheduler for."""

    cpu: Quantity
    memory: Quantity
    gpu: NonNegInt = 0


class ProfileEntry(FogModel):
    """One row of the execution-time look-up table (Fig. 3): mean and spread at a CPU limit.

    ``hardwareType: default`` applies to nodes whose type has no rows, scaled by their
    ``speedFactor``.
    """

    hardware_type: Annotated[str, Field(min_length=1, max_length=63)]
    cpu: Quantity
    mean_millis: Quantity
    std_millis: Quantity = 0


class Topic(FogModel):
    """A ROS 2 topic the module exchanges with its robot, with message size and rate."""

    name: Annotated[str, Field(min_length=1)]
    size_bytes: Quantity
    rate_hz: Quantity


class Topics(FogModel):
    subscribes: list[Topic] = Field(default_factory=list)
    publishes: list[Topic] = Field(default_factory=list)


class Requirements(FogModel):
    devices: list[DeviceType] = Field(default_factory=list)
    gpu: bool = False
    realtime_kernel: bool = False
    min_privacy: Annotated[int, Field(ge=0, le=3)] = 0
    tiers: list[Tier] = Field(
        default_factory=list, description="Tiers the module may run on (empty: any allowed)."
    )


class SoftwareModuleSpec(FogModel):
    template: ContainerTemplate
    taxonomy: Taxonomy
    cycle_time_millis: Quantity
    activation_percent: Annotated[int, Field(ge=1, le=100)] = 100
    resources: ModuleResources
    profile: list[ProfileEntry] = Field(min_length=1)
    topics: Topics = Field(default_factory=Topics)
    requirements: Requirements = Field(default_factory=Requirements)
    scope: Scope = Scope.PER_ROBOT
    replicas: PosInt = Field(default=1, description="Replicas of a shared module.")
    scaling: ScalingSpec | None = Field(
        default=None, description="SLO-driven autoscaling of a shared module (tinyKube)."
    )

    @model_validator(mode="after")
    def _check(self) -> SoftwareModuleSpec:
        if parse_quantity(self.cycle_time_millis) <= 0:
            raise ValueError("cycleTimeMillis: must be greater than zero")
        for k, row in enumerate(self.profile):
            if parse_quantity(row.cpu) <= 0:
                raise ValueError(f"profile[{k}].cpu: must be greater than zero")
            if parse_quantity(row.mean_millis) <= 0:
                raise ValueError(f"profile[{k}].meanMillis: must be greater than zero")
        if self.scope is Scope.SHARED and self.taxonomy.realtime is RealtimeClass.HARD:
            raise ValueError("scope: a hard real-time module must be perRobot (it runs on board)")
        if self.scaling is not None and self.scope is not Scope.SHARED:
            raise ValueError(
                "scaling: only shared modules scale; per-robot modules run once per robot"
            )
        if self.scope is Scope.SHARED and self.taxonomy.safety is SafetyClass.CRITICAL:
            raise ValueError("scope: a safety-critical module must be perRobot (it runs on board)")
        return self


class PoolStatus(FogModel):
    tier: str
    replicas: int
    ready: int | None = None


class ScalingStatus(FogModel):
    """The autoscaler's last decision; RobotFleets place this many replicas per tier."""

    desired_replicas: int
    pools: list[PoolStatus] = Field(default_factory=list)
    reason: str = ""
    metrics_available: bool = True
    last_decision_time: str | None = None
    last_scale_time: str | None = None
    observed_slo_millis: float | None = None
    # tinyKube III-B admission forecast: fractions of each class the pools would reject
    predicted_private_rejected: float | None = None
    predicted_normal_rejected: float | None = None


class SoftwareModuleStatus(FogModel):
    observed_generation: int | None = None
    conditions: list[Condition] = Field(default_factory=list)
    scaling: ScalingStatus | None = None
    offloadable: Literal["never", "candidate", "preferred"] | None = None
    fleets: list[str] = Field(default_factory=list)


class SoftwareModule(FogModel):
    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["SoftwareModule"] = "SoftwareModule"
    metadata: ObjectMeta
    spec: SoftwareModuleSpec
    status: SoftwareModuleStatus | None = None


Name_ = Name  # re-exported for fleets' references
