"""SoftwareModule (namespaced): one containerised ROS 2 module of the robot software stack.

The taxonomy follows multi-robot-edge-cloud-scheduling III-A (Fig. 2): execution pattern,
real-time class and safety class. ``cycleTimeMillis`` and ``activationPercent`` are Table II's
"max. cycle time" and "avg. execution rate"; ``profile`` is the look-up table of Fig. 3
(execution time per hardware type and CPU limit).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, ClassVar, Literal

from pydantic import Field, model_validator

from fogfleet.api.kinds import SOFTWAREMODULES

from .base import (
    FogModel,
    NonNegInt,
    Number,
    PosInt,
    Quantity,
    parse_millis,
    parse_quantity,
    refuse_duplicates,
)
from .common import Condition, ObjectMeta, Tier
from .computenode import DeviceType
from .dnn import Dnn
from .fallback import STANDING_BY, Fallback
from .observed import ObservedRow, ProfileCorrection
from .profiling import Profiling, ProfilingMode, ProfilingStatus
from .rules import CrossFieldRule, enforce
from .scaling import ScalingSpec
from .template import ContainerTemplate

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
    "auto_profiled",
    "default_priority",
]


class ExecutionPattern(StrEnum):
    """How the module runs (III-A): all the time, on a fixed period, or on events."""

    CONTINUOUS = "continuous"
    PERIODIC = "periodic"
    EVENT = "event"


class RealtimeClass(StrEnum):
    """Real-time class (III-A): a missed deadline is a failure (hard), a loss (soft), or neither."""

    HARD = "hard"
    SOFT = "soft"
    NONE = "none"


class SafetyClass(StrEnum):
    """Safety class (III-A): critical modules never leave their robot."""

    CRITICAL = "critical"
    RELEVANT = "relevant"
    IRRELEVANT = "irrelevant"


class Scope(StrEnum):
    """perRobot: one instance on or for every robot. shared: replicas that serve the fleet."""

    PER_ROBOT = "perRobot"
    SHARED = "shared"


def default_priority(tax: Taxonomy) -> int:
    """A module's priority when ``spec.priority`` is not set, from its taxonomy (III-A):
    hard real-time or safety-critical 1000 (never degraded anyway), safety-relevant 700,
    soft real-time 400, the rest 100."""
    if must_run_on_board(tax):
        return 1000
    if tax.safety is SafetyClass.RELEVANT:
        return 700
    if tax.realtime is RealtimeClass.SOFT:
        return 400
    return 100


def must_run_on_board(tax: Taxonomy) -> bool:
    """III-B: hard real-time and safety-critical modules run on their own robot."""
    return tax.realtime is RealtimeClass.HARD or tax.safety is SafetyClass.CRITICAL


class Taxonomy(FogModel):
    """The robotics taxonomy of III-A (Fig. 2); it decides where a module may run at all."""

    execution_pattern: ExecutionPattern
    """continuous, periodic or event (event-driven and periodic modules offload first)."""
    realtime: RealtimeClass
    """hard (runs on its own robot), soft or none."""
    safety: SafetyClass
    """critical (runs on its own robot), relevant or irrelevant."""


class ModuleResources(FogModel):
    """The module's nominal request: what a plain Deployment would ask kube-scheduler for."""

    cpu: Quantity
    """CPU cores a plain Deployment would request ("500m")."""
    memory: Quantity
    """Memory in bytes, requested and limited wherever the module runs ("512Mi")."""
    gpu: NonNegInt = 0
    """GPUs requested (nvidia.com/gpu)."""


class ProfileEntry(FogModel):
    """One row of the execution-time look-up table (Fig. 3): mean and spread at a CPU limit.

    ``hardwareType: default`` applies to nodes whose type has no rows, scaled by their
    ``speedFactor``.
    """

    hardware_type: Annotated[str, Field(min_length=1, max_length=63)]
    """A ComputeNode hardwareType, or default for nodes without rows of their own."""
    cpu: Quantity
    """The CPU limit this row was measured at, in cores ("2", "500m")."""
    mean_millis: Number
    """Mean execution time of one cycle at this limit, in milliseconds."""
    std_millis: Number = 0
    """Standard deviation of the execution time, in milliseconds."""


class Topic(FogModel):
    """A ROS 2 topic the module exchanges with its robot, with message size and rate."""

    name: Annotated[str, Field(min_length=1)]
    """Absolute topic name (/scan)."""
    size_bytes: Quantity
    """Size of one message in bytes (eq. 4's transfer term)."""
    rate_hz: Number
    """Messages per second."""


class Topics(FogModel):
    """The topics the module exchanges with its robot: they cost uplink when it offloads."""

    subscribes: list[Topic] = Field(default_factory=list)
    """Topics the module reads; the first one triggers its cycles in the workload image."""
    publishes: list[Topic] = Field(default_factory=list)
    """Topics the module writes."""

    @model_validator(mode="after")
    def _unique(self) -> Topics:
        refuse_duplicates([t.name for t in self.subscribes], "subscribes")
        refuse_duplicates([t.name for t in self.publishes], "publishes")
        return self


class Requirements(FogModel):
    """Hard constraints on the nodes a module may run on (MBSE deployment rules)."""

    devices: list[DeviceType] = Field(default_factory=list)
    """Device types the module reads; it runs only on nodes that have them."""
    gpu: bool = False
    """The module needs a node with a GPU."""
    realtime_kernel: bool = False
    """The module needs a node with a real-time kernel."""
    min_privacy: Annotated[int, Field(ge=0, le=3)] = 0
    """The module runs only on nodes whose privacyLevel is at least this (0-3)."""
    tiers: list[Tier] = Field(
        default_factory=list, description="Tiers the module may run on (empty: any allowed)."
    )

    @model_validator(mode="after")
    def _unique(self) -> Requirements:
        refuse_duplicates([d.value for d in self.devices], "devices")
        refuse_duplicates([t.value for t in self.tiers], "tiers")
        return self


_ONBOARD = (
    "(has(self.fallback) && has(self.fallback.mode) && "
    "(self.fallback.mode == 'onboard' || self.fallback.mode == 'variant'))"
)


def _onboard(spec: SoftwareModuleSpec) -> bool:
    """The module keeps a standby on its robot (fallback mode onboard or variant)."""
    return spec.fallback is not None and spec.fallback.mode in STANDING_BY


_AUTO = "(has(self.profiling) && has(self.profiling.mode) && self.profiling.mode == 'auto')"

# A dnn module (RoboEC2's split network): a per-robot module that may leave its robot, whose
# times and fallback (its local model) are stated in dnn alone.
DNN_RULES = (
    CrossFieldRule(
        "!has(self.dnn) || !has(self.scope) || self.scope == 'perRobot'",
        "dnn: a split network runs its head on a robot, so the module must be perRobot",
        lambda s: s.dnn is None or s.scope is Scope.PER_ROBOT,
    ),
    CrossFieldRule(
        "!has(self.dnn) || (self.taxonomy.realtime != 'hard' && self.taxonomy.safety != "
        "'critical')",
        "dnn: a hard real-time or safety-critical module stays whole on its robot, so its "
        "network cannot be split",
        lambda s: s.dnn is None or not must_run_on_board(s.taxonomy),
    ),
    CrossFieldRule(
        "!has(self.dnn) || !has(self.profile) || size(self.profile) == 0",
        "profile: a dnn module's times are dnn's (fullMillis, the split points, the local "
        "model); leave profile empty",
        lambda s: s.dnn is None or not s.profile,
    ),
    CrossFieldRule(
        f"!has(self.dnn) || {_AUTO} || (has(self.dnn.inputBytes) && has(self.dnn.outputBytes) "
        "&& has(self.dnn.fullMillis) && has(self.dnn.localModel.robotMillis) && "
        "(!has(self.dnn.splitPoints) || self.dnn.splitPoints.all(p, has(p.headMillis) && "
        "has(p.tailMillis) && has(p.tensorBytes))))",
        "dnn: inputBytes, outputBytes, fullMillis, localModel.robotMillis and every split "
        "point's headMillis, tailMillis and tensorBytes are needed, unless profiling.mode is "
        "auto (the operator then measures them on each hardware type)",
        lambda s: s.dnn is None or auto_profiled(s) or not s.dnn.missing(),
    ),
    CrossFieldRule(
        f"!has(self.dnn) || !{_AUTO} || (!has(self.dnn.inputBytes) && "
        "!has(self.dnn.outputBytes) && !has(self.dnn.fullMillis) && "
        "!has(self.dnn.localModel.robotMillis) && (!has(self.dnn.splitPoints) || "
        "self.dnn.splitPoints.all(p, !has(p.headMillis) && !has(p.tailMillis) && "
        "!has(p.tensorBytes))))",
        "dnn: with profiling.mode auto the operator measures inputBytes, outputBytes, "
        "fullMillis, localModel.robotMillis and the split points' times and bytes on each "
        "hardware type; leave them out (times known for a hardware type go in dnn.profiles)",
        lambda s: s.dnn is None or not auto_profiled(s) or not s.dnn.declared(),
    ),
    CrossFieldRule(
        "!has(self.dnn) || !has(self.fallback)",
        "fallback: a dnn module falls back to dnn.localModel on its robot; leave fallback unset",
        lambda s: s.dnn is None or s.fallback is None,
    ),
    CrossFieldRule(
        "!has(self.dnn) || !has(self.dnn.maxLatencyMillis) || "
        "self.dnn.maxLatencyMillis <= self.cycleTimeMillis",
        "dnn.maxLatencyMillis: at most cycleTimeMillis (a frame's answer comes before the next "
        "frame)",
        lambda s: (
            s.dnn is None
            or s.dnn.max_latency_millis is None
            or s.dnn.max_latency_millis <= parse_quantity(s.cycle_time_millis)
        ),
    ),
)


def auto_profiled(spec: SoftwareModuleSpec) -> bool:
    """The operator profiles the module where it has no rows (profiling.mode auto)."""
    return spec.profiling is not None and spec.profiling.mode is ProfilingMode.AUTO


class SoftwareModuleSpec(FogModel):
    """One containerised ROS 2 module: what it runs, how it behaves, what it needs."""

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "!has(self.scope) || self.scope != 'shared' || "
            "(self.taxonomy.realtime != 'hard' && self.taxonomy.safety != 'critical')",
            "scope: a hard real-time or safety-critical module must be perRobot (it runs on board)",
            lambda s: s.scope is not Scope.SHARED or not must_run_on_board(s.taxonomy),
        ),
        CrossFieldRule(
            "!(has(self.requirements) && has(self.requirements.gpu) && self.requirements.gpu)"
            " || (has(self.resources.gpu) && self.resources.gpu > 0)",
            "resources.gpu: requirements.gpu is true but no GPU is requested; set "
            "resources.gpu (e.g. 1) so the pod gets one",
            lambda s: not s.requirements.gpu or s.resources.gpu > 0,
        ),
        CrossFieldRule(
            "!(has(self.resources.gpu) && self.resources.gpu > 0) || (has(self.requirements) "
            "&& has(self.requirements.gpu) && self.requirements.gpu)",
            "requirements.gpu: resources.gpu requests GPUs; set requirements.gpu: true so the "
            "module is planned on a node that has them",
            lambda s: s.resources.gpu == 0 or s.requirements.gpu,
        ),
        CrossFieldRule(
            f"!{_ONBOARD} || !has(self.scope) || self.scope != 'shared'",
            "fallback.mode: onboard and variant need a robot to fall back to and a shared module "
            "has none (use scope perRobot, or fallback.mode none)",
            lambda s: not _onboard(s) or s.scope is not Scope.SHARED,
        ),
        CrossFieldRule(
            "(has(self.profile) && size(self.profile) > 0) || (has(self.profiling) && "
            "has(self.profiling.mode) && self.profiling.mode == 'auto') || has(self.dnn)",
            "profile: at least one row, unless profiling.mode is auto (the operator then "
            "profiles the module on each hardware type it needs) or dnn gives the times",
            lambda s: bool(s.profile) or auto_profiled(s) or s.dnn is not None,
        ),
        *DNN_RULES,
        CrossFieldRule(
            f"!{_ONBOARD} || (has(self.topics) && has(self.topics.publishes) && "
            "size(self.topics.publishes) > 0)",
            "fallback.mode: onboard and variant need topics.publishes: the standby watches the "
            "module's outputs to notice that the remote instance went silent",
            lambda s: not _onboard(s) or bool(s.topics.publishes),
        ),
    )

    template: ContainerTemplate
    """The container fogfleet deploys for each instance."""
    taxonomy: Taxonomy
    """Execution pattern, real-time and safety class (III-A)."""
    cycle_time_millis: Number
    """Deadline of one cycle in milliseconds (Table II's max. cycle time); a cycle that ends
    later is missed (F4)."""
    activation_percent: Annotated[int, Field(ge=1, le=100)] = 100
    """Share of time the module is active, 1-100 (Table II's avg. execution rate)."""
    resources: ModuleResources
    """The nominal request of a plain Deployment (and the module's memory)."""
    profile: list[ProfileEntry] = Field(default_factory=list)
    """Execution time per hardware type and CPU limit (Fig. 3's look-up table). May be empty
    with profiling.mode auto."""
    profiling: Profiling | None = None
    """Profile the module with short Jobs on a hardware type that has no rows (mode auto)
    before planning it there. Unset: off."""
    topics: Topics = Field(default_factory=Topics)
    """ROS 2 topics exchanged with the robot (default: none)."""
    requirements: Requirements = Field(default_factory=Requirements)
    """Hard placement constraints (default: none)."""
    scope: Scope = Scope.PER_ROBOT
    """perRobot (an instance per robot) or shared (replicas serving the whole fleet)."""
    replicas: PosInt = Field(default=1, description="Replicas of a shared module.")
    scaling: ScalingSpec | None = Field(
        default=None, description="SLO-driven autoscaling of a shared module (tinyKube)."
    )
    preferred_tiers: list[Tier] = Field(default_factory=list)
    """Tiers this module should run on when it can (a preference; requirements.tiers is the
    rule): among plans that miss alike, the one with the fewest instances elsewhere wins,
    before the cheaper. A fleet may override it per module. Empty: no preference."""
    priority: Annotated[int, Field(ge=1, le=1000)] | None = None
    """How much this module's deadlines matter, 1-1000 (higher matters more). When the site is
    short of CPU, fogfleet gives the lowest-priority modules a smaller profiled CPU first and
    reports their predicted misses (a Degraded plan) instead of refusing the fleet. Hard
    real-time and safety-critical modules are never degraded. Default from the taxonomy:
    700 for safety-relevant modules, 400 for soft real-time ones, 100 for the rest."""
    dnn: Dnn | None = None
    """The module's network can be cut between its robot and an off-board node (RoboEC2): its
    split points, its robot's local model and the bounds a frame must meet. The planner places
    the network's tail and picks the split from each candidate node's link; the head and the
    local model stay on the robot. Unset: the module runs whole where it is placed."""
    fallback: Fallback | None = None
    """What runs when the module is offloaded and its robot's link fails: onboard keeps a
    standby on the robot (its on-board share reserved) that takes over on its own; variant
    keeps a standby running a lighter variant module. Unset: the fleet's spec.fallback."""

    @property
    def cycle_seconds(self) -> float:
        """``cycleTimeMillis`` in seconds, the unit of the planner, simulator and autoscaler."""
        return parse_millis(self.cycle_time_millis)

    @model_validator(mode="after")
    def _check(self) -> SoftwareModuleSpec:
        if parse_quantity(self.cycle_time_millis) <= 0:
            raise ValueError("cycleTimeMillis: must be greater than zero")
        refuse_duplicates(
            [f"{r.hardware_type}@{parse_quantity(r.cpu):g}" for r in self.profile], "profile"
        )
        for k, row in enumerate(self.profile):
            if parse_quantity(row.cpu) <= 0:
                raise ValueError(f"profile[{k}].cpu: must be greater than zero")
            if parse_quantity(row.mean_millis) <= 0:
                raise ValueError(f"profile[{k}].meanMillis: must be greater than zero")
        enforce(self, self.RULES)
        refuse_duplicates([t.value for t in self.preferred_tiers], "preferredTiers")
        if self.scaling is not None and self.scope is not Scope.SHARED:
            raise ValueError(
                "scaling: only shared modules scale; per-robot modules run once per robot"
            )
        return self


class PoolStatus(FogModel):
    """The replicas the autoscaler wants in one tier."""

    tier: str
    """edge or cloud."""
    replicas: int
    """Replicas wanted in this tier."""
    ready: int | None = None
    """Replicas ready in this tier."""


class ScalingStatus(FogModel):
    """The autoscaler's last decision; RobotFleets place this many replicas per tier."""

    desired_replicas: int
    """Replicas the autoscaler wants in total."""
    pools: list[PoolStatus] = Field(default_factory=list)
    """Replicas per tier."""
    reason: str = ""
    """Why the autoscaler decided so."""
    metrics_available: bool = True
    """Prometheus answered the last query; when false the replicas are held."""
    last_decision_time: str | None = None
    """When the autoscaler last decided (RFC 3339)."""
    last_scale_time: str | None = None
    """When the replica count last changed (RFC 3339)."""
    observed_slo_millis: float | None = None
    """The SLO metric's last value, in milliseconds."""
    predicted_private_rejected: float | None = None
    """Fraction of private requests the pools would reject (tinyKube III-B forecast)."""
    predicted_normal_rejected: float | None = None
    """Fraction of normal requests the pools would reject (tinyKube III-B forecast)."""


class SoftwareModuleStatus(FogModel):
    """What the operator decided about the module (written by the operator)."""

    observed_generation: int | None = None
    """The metadata.generation this status describes."""
    conditions: list[Condition] = Field(default_factory=list)
    """Scaling and MetricsUnavailable: the autoscaler's state (modules with spec.scaling)."""
    scaling: ScalingStatus | None = None
    """The autoscaler's last decision."""
    offloadable: Literal["never", "candidate", "preferred"] | None = None
    """The taxonomy's verdict (III-A): never (stays on its robot), candidate, or preferred
    (offloaded first)."""
    fleets: list[str] = Field(default_factory=list)
    """RobotFleets (in this namespace) whose plan places this module."""
    instances: int | None = None
    """Instances placed by all those plans."""
    split: str | None = None
    """Instances on robots/edge/cloud, as "3/2/0" (like the RobotFleet's split)."""
    measured_miss_rate: float | None = None
    """Measured fraction of this module's missed cycles (0-1) over the fleets that place it
    (their status.measured, each weighed by its cycles). Unset until cycles are measured
    (never 0 for "not measured"): measuring needs the operator's Prometheus."""
    measured_miss: str | None = None
    """measuredMissRate as people read it, in the RobotFleet predictedMiss's format (kubectl's
    MEASURED column)."""
    observed: list[ObservedRow] = Field(default_factory=list)
    """Execution times measured where the module runs, per hardware type and CPU limit."""
    profile_correction: list[ProfileCorrection] = Field(default_factory=list)
    """Per hardware type, the factor the planner multiplies the declared profile by (set
    when a fleet's drift showed the declared profile wrong)."""
    profiling: ProfilingStatus | None = None
    """Automatic profiling: its runs per hardware type and the rows it found (used like
    declared rows)."""


class SoftwareModule(FogModel):
    """One containerised ROS 2 module of the robot software stack."""

    PLURAL: ClassVar[str] = SOFTWAREMODULES
    """The resource name in API paths (``/apis/fogfleet.io/v1alpha1/.../softwaremodules``)."""

    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["SoftwareModule"] = "SoftwareModule"
    metadata: ObjectMeta
    spec: SoftwareModuleSpec
    status: SoftwareModuleStatus | None = None
