"""SoftwareModule (namespaced): one containerised ROS 2 module of the robot software stack.

The taxonomy follows multi-robot-edge-cloud-scheduling III-A (Fig. 2): execution pattern,
real-time class and safety class. ``cycleTimeMillis`` and ``activationPercent`` are Table II's
"max. cycle time" and "avg. execution rate"; ``profile`` is the look-up table of Fig. 3
(execution time per hardware type and CPU limit).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from .base import FogModel, NonNegInt, PosInt, Quantity, parse_quantity, refuse_duplicates
from .common import Condition, Name, ObjectMeta, Tier
from .computenode import DeviceType
from .podtemplate import (
    OWNED_POD_FIELDS,
    ContainerPort,
    EnvFromSource,
    EnvVarSource,
    Probe,
    SecurityContext,
    Sidecar,
    Toleration,
    Volume,
    VolumeMount,
)
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


class Taxonomy(FogModel):
    """The robotics taxonomy of III-A (Fig. 2); it decides where a module may run at all."""

    execution_pattern: ExecutionPattern
    """continuous, periodic or event (event-driven and periodic modules offload first)."""
    realtime: RealtimeClass
    """hard (runs on its own robot), soft or none."""
    safety: SafetyClass
    """critical (runs on its own robot), relevant or irrelevant."""


class EnvVar(FogModel):
    """An environment variable of the module's container: a value, or valueFrom."""

    name: Annotated[str, Field(min_length=1)]
    """Variable name; FOGFLEET_*, ROS_*, RMW_*, FASTDDS_* and FASTRTPS_* belong to fogfleet."""
    value: str = ""
    """Variable value."""
    value_from: EnvVarSource | None = None
    """Take the value from a Secret, a ConfigMap or the pod (instead of value)."""

    @model_validator(mode="after")
    def _value_or_source(self) -> EnvVar:
        if self.value and self.value_from is not None:
            raise ValueError(f"{self.name}: set value or valueFrom, not both")
        return self


class LocalRef(FogModel):
    """An object of the module's namespace, by name."""

    name: Annotated[str, Field(min_length=1, max_length=253)]
    """Its name."""


# Environment fogfleet owns in every module container (the ROS wiring and FOGFLEET_*).
RESERVED_ENV_PREFIXES = ("FOGFLEET_", "ROS_", "RMW_", "FASTDDS_", "FASTRTPS_")


def _reserved_env(names: list[str], field: str) -> None:
    for k, name in enumerate(names):
        if name.startswith(RESERVED_ENV_PREFIXES):
            raise ValueError(
                f"{field}[{k}].name: {name} is set by fogfleet (the ROS 2 wiring and "
                f"FOGFLEET_* variables: {', '.join(RESERVED_ENV_PREFIXES)}); configure it "
                "in the RobotFleet's spec.ros instead"
            )


class ContainerTemplate(FogModel):
    """The module's pod: its container and the pod-template subset ROS 2 modules need.
    fogfleet adds placement (node affinity), CPU, memory, labels and the ROS 2 wiring, and
    restricted security defaults wherever this template says nothing."""

    image: Annotated[str, Field(min_length=1)]
    """Container image of the module (e.g. ghcr.io/fogfleet/ros2-module:0.1.0)."""
    image_pull_policy: Literal["Always", "IfNotPresent", "Never"] | None = None
    """Kubernetes imagePullPolicy (default: Kubernetes' own, from the image tag)."""
    command: list[str] = Field(default_factory=list)
    """Entrypoint override (default: the image's)."""
    args: list[str] = Field(default_factory=list)
    """Arguments (default: the image's)."""
    env: list[EnvVar] = Field(default_factory=list)
    """Extra environment variables; names fogfleet sets are refused."""
    env_from: list[EnvFromSource] = Field(default_factory=list)
    """Every key of a ConfigMap or Secret as variables."""
    ports: list[ContainerPort] = Field(default_factory=list)
    """Ports the module listens on (besides metricsPort)."""
    volumes: list[Volume] = Field(default_factory=list)
    """Volumes of the pod: parameters and maps (ConfigMap, PVC), devices (hostPath), scratch."""
    volume_mounts: list[VolumeMount] = Field(default_factory=list)
    """Where the volumes appear in the module's container (a writable /tmp is always there)."""
    liveness_probe: Probe | None = None
    """Restart the container when this fails (default with metricsPort: GET /healthz)."""
    readiness_probe: Probe | None = None
    """Count the pod ready when this passes (default with metricsPort: GET /healthz)."""
    startup_probe: Probe | None = None
    """Hold the other probes until this passes (slow-starting modules)."""
    security_context: SecurityContext | None = None
    """Exceptions to the restricted defaults (non-root, no privilege escalation, no
    capabilities, seccomp RuntimeDefault, read-only root filesystem)."""
    extra_resources: dict[str, Quantity] = Field(default_factory=dict)
    """Device-plugin resources requested and limited, e.g. {"squat.ai/video": 1}; GPUs come
    from spec.resources.gpu."""
    tolerations: list[Toleration] = Field(default_factory=list)
    """Taints the pod tolerates (robot computers are often tainted for their own modules)."""
    image_pull_secrets: list[LocalRef] = Field(default_factory=list)
    """Secrets to pull private images with."""
    service_account_name: Annotated[str, Field(min_length=1, max_length=253)] | None = None
    """The pod's ServiceAccount (default: the namespace's default)."""
    automount_service_account_token: bool = False
    """Mount the ServiceAccount's API token (only modules that call the Kubernetes API)."""
    sidecars: list[Sidecar] = Field(default_factory=list)
    """Extra containers in the pod (e.g. fogfleet's cycle-time probe)."""
    metrics_port: Annotated[int, Field(ge=1, le=65535)] | None = Field(
        default=None,
        description=(
            "Port on which the module serves the metrics contract (/metrics) and /healthz: "
            "fogfleet then adds the port, liveness and readiness probes and Prometheus "
            "scrape annotations. The ROS 2 workload image serves 9100."
        ),
    )

    def metrics_ports(self) -> list[int]:
        """Every port serving the metrics contract: the module's and its sidecars'."""
        ports = [self.metrics_port, *(c.metrics_port for c in self.sidecars)]
        return [p for p in ports if p]

    @model_validator(mode="before")
    @classmethod
    def _owned_fields(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for key, why in OWNED_POD_FIELDS.items():
                if key in data:
                    raise ValueError(f"{key}: set by fogfleet ({why})")
        return data

    @model_validator(mode="after")
    def _consistent(self) -> ContainerTemplate:
        _reserved_env([e.name for e in self.env], "env")
        for k, car in enumerate(self.sidecars):
            _reserved_env([e.name for e in car.env], f"sidecars[{k}].env")
        volumes = {v.name for v in self.volumes}
        _unique([v.name for v in self.volumes], "volumes", "name")
        _unique([c.name for c in self.sidecars], "sidecars", "name")
        mounts = [("volumeMounts", m) for m in self.volume_mounts] + [
            (f"sidecars[{k}].volumeMounts", m)
            for k, car in enumerate(self.sidecars)
            for m in car.volume_mounts
        ]
        for field, mount in mounts:
            if mount.name not in volumes:
                raise ValueError(
                    f"{field}: volume {mount.name} is not in volumes "
                    f"({', '.join(sorted(volumes)) or 'none'})"
                )
            if mount.mount_path == "/tmp":
                raise ValueError(f"{field}: /tmp is fogfleet's writable scratch; mount elsewhere")
        ports = [p.container_port for p in self.ports] + [
            p.container_port for car in self.sidecars for p in car.ports
        ]
        ports += [x for x in [self.metrics_port] if x] + [
            car.metrics_port for car in self.sidecars if car.metrics_port
        ]
        _unique([str(p) for p in ports], "ports", "containerPort")
        if self.metrics_port and any(p.name == "metrics" for p in self.ports):
            raise ValueError("ports: the name metrics is fogfleet's (metricsPort)")
        return self


def _unique(values: list[str], field: str, key: str) -> None:
    seen: set[str] = set()
    for k, value in enumerate(values):
        if value in seen:
            raise ValueError(f"{field}[{k}].{key}: {value} appears twice")
        seen.add(value)


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
    mean_millis: Quantity
    """Mean execution time of one cycle at this limit, in milliseconds."""
    std_millis: Quantity = 0
    """Standard deviation of the execution time, in milliseconds."""


class Topic(FogModel):
    """A ROS 2 topic the module exchanges with its robot, with message size and rate."""

    name: Annotated[str, Field(min_length=1)]
    """Absolute topic name (/scan)."""
    size_bytes: Quantity
    """Size of one message in bytes (eq. 4's transfer term)."""
    rate_hz: Quantity
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


class SoftwareModuleSpec(FogModel):
    """One containerised ROS 2 module: what it runs, how it behaves, what it needs."""

    template: ContainerTemplate
    """The container fogfleet deploys for each instance."""
    taxonomy: Taxonomy
    """Execution pattern, real-time and safety class (III-A)."""
    cycle_time_millis: Quantity
    """Deadline of one cycle in milliseconds (Table II's max. cycle time); a cycle that ends
    later is missed (F4)."""
    activation_percent: Annotated[int, Field(ge=1, le=100)] = 100
    """Share of time the module is active, 1-100 (Table II's avg. execution rate)."""
    resources: ModuleResources
    """The nominal request of a plain Deployment (and the module's memory)."""
    profile: list[ProfileEntry] = Field(min_length=1)
    """Execution time per hardware type and CPU limit (Fig. 3's look-up table)."""
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


class SoftwareModule(FogModel):
    """One containerised ROS 2 module of the robot software stack."""

    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["SoftwareModule"] = "SoftwareModule"
    metadata: ObjectMeta
    spec: SoftwareModuleSpec
    status: SoftwareModuleStatus | None = None


Name_ = Name  # re-exported for fleets' references
