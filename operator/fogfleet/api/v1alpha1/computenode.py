"""ComputeNode (cluster-scoped): a Kubernetes node as fogfleet sees it.

A robot's on-board computer, an edge server or a cloud VM. The hardware type keys the modules'
execution-time profiles (multi-robot-edge-cloud-scheduling III-E, Fig. 3); devices carry the
MBSE deployment constraints (cloud-native-fog-robotics-mbse, OCL); privacy level follows
tinyKube; power figures follow fog-iot-resource-optimization (battery model).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, ClassVar, Literal

from pydantic import Field, model_validator

from fogfleet.api.kinds import COMPUTENODES

from .base import FogModel, NonNegInt, Number, Quantity, refuse_duplicates
from .common import Condition, Name, ObjectMeta, Tier
from .rules import CrossFieldRule, enforce

# a ManagedCluster's name: the namespace of its ManifestWorks on the hub (a DNS label)
ClusterName = Annotated[
    str, Field(min_length=1, max_length=63, pattern=r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")
]

__all__ = [
    "ComputeNode",
    "ComputeNodeSpec",
    "ComputeNodeStatus",
    "Device",
    "DeviceType",
    "LinkType",
    "NetworkLink",
    "NodeResources",
    "PowerModel",
]


class DeviceType(StrEnum):
    """A kind of device a module may need (MBSE deployment constraints)."""

    CAMERA = "camera"
    DEPTH_CAMERA = "depth-camera"
    LIDAR = "lidar"
    IMU = "imu"
    GPS = "gps"
    ARM = "arm"
    SERIAL = "serial"
    OTHER = "other"


class LinkType(StrEnum):
    """Link types of the paper's latency model (III-E): Wi-Fi, LAN, Ethernet to cloud (WAN)."""

    LOOPBACK = "loopback"
    WIFI = "wifi"
    LAN = "lan"
    WAN = "wan"
    CELLULAR = "cellular"


class Device(FogModel):
    """A device attached to the node; modules that read it must run here."""

    name: Name
    """The device's name on this node (e.g. front-camera)."""
    type: DeviceType
    """What kind of device it is; modules list the types they need in requirements.devices."""


class NodeResources(FogModel):
    """Allocatable resources of the node."""

    cpu: Quantity
    """CPU cores, as a quantity ("8", "7500m")."""
    memory: Quantity
    """Memory in bytes, as a quantity ("32Gi")."""
    gpu: NonNegInt = 0
    """Number of GPUs (device-plugin resources the modules may request)."""


class ReservedResources(FogModel):
    """Resources kept free for the system and for what fogfleet does not plan."""

    cpu: Quantity = 0
    """CPU cores never given to planned modules."""
    memory: Quantity = 0
    """Memory in bytes never given to planned modules."""


class NetworkLink(FogModel):
    """The node's uplink. A robot reaches an edge node over its own link plus the edge node's.

    Latency and jitter in milliseconds, bandwidth in megabit/s, loss in percent; all quantity
    strings ("2.5") or integers.
    """

    type: LinkType
    """Link technology; Wi-Fi and cellular links are the robot side of eq. 4's transfer time."""
    latency_millis: Number
    """One-way latency of this link in milliseconds (eq. 4's latency term)."""
    jitter_millis: Number = 0
    """Standard deviation of the one-way latency in milliseconds."""
    bandwidth_mbps: Number
    """Usable bandwidth in megabit/s (eq. 4's size/bandwidth term; 80% is the planning cap)."""
    loss_percent: Number = 0
    """Packet loss in percent."""


class PowerModel(FogModel):
    """Robot energy model (fog-iot-resource-optimization): idle + per busy core + radio."""

    battery_watt_hours: Number
    """Battery capacity in watt-hours."""
    idle_watts: Number = 0
    """Power drawn by the computer when idle, in watts."""
    per_core_watts: Number = 0
    """Extra power per busy core, in watts."""
    radio_watts_per_mbps: Number = 0
    """Radio power per megabit/s sent or received, in watts."""


class ComputeNodeSpec(FogModel):
    """What fogfleet needs to know about a Kubernetes node to place modules on it."""

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "!has(self.power) || self.tier == 'robot'",
            "power: only robot nodes have a battery model",
            lambda s: s.power is None or s.tier is Tier.ROBOT,
        ),
        CrossFieldRule(
            "!has(self.managedCluster) || self.tier != 'robot'",
            "managedCluster: a robot's own computer is not a cluster of its own",
            lambda s: s.managed_cluster is None or s.tier is not Tier.ROBOT,
        ),
        CrossFieldRule(
            "!has(self.managedCluster) || !has(self.nodeName)",
            "nodeName: a node that stands for a managed cluster has no Kubernetes Node here",
            lambda s: s.managed_cluster is None or s.node_name is None,
        ),
    )

    node_name: Name | None = Field(
        default=None, description="The Kubernetes Node this describes (default: metadata.name)."
    )
    tier: Tier
    """robot (a robot's own computer), edge (on the site's LAN) or cloud (over the WAN)."""
    hardware_type: Annotated[str, Field(min_length=1, max_length=63)]
    """Key into the modules' execution-time profiles (Fig. 3), e.g. jetson-orin or D16s_v3."""
    capacity: NodeResources | None = Field(
        default=None,
        description="Allocatable resources. The operator reads them from the Node when omitted.",
    )
    reserved: ReservedResources = Field(default_factory=ReservedResources)
    """Resources kept free on this node (default: none)."""
    speed_factor: Number = Field(
        default=1,
        description="Relative CPU speed, used only when no profile names this hardware type.",
    )
    devices: list[Device] = Field(default_factory=list)
    """Devices attached to this node (cameras, lidars, arms...)."""
    realtime_kernel: bool = False
    """The node runs a real-time (PREEMPT_RT) kernel; hard real-time modules may need one."""
    privacy_level: Annotated[int, Field(ge=0, le=3)] | None = None
    """How private the data a node may see can be, 0 (public) to 3 (robot only) (tinyKube);
    a module runs only where privacyLevel >= its requirements.minPrivacy. Default: 3 on a
    robot (a robot trusts its own computer), 0 elsewhere."""
    cost_per_core_hour: Number = 0
    """Price of one core for one hour, in the fleet's currency (the cost objective)."""
    power: PowerModel | None = None
    """Battery and power model of a robot (robot nodes only; the energy objective)."""
    network: list[NetworkLink] = Field(default_factory=list, max_length=8)
    """The node's uplinks; the first is the one the planner uses (at most 8)."""
    managed_cluster: ClusterName | None = None
    """An Open Cluster Management ManagedCluster this node stands for: a cluster of its own
    (a cloud), reached over the WAN. The operator places the instances planned here through
    ManifestWorks on the OCM hub (FOGFLEET_HUB_KUBECONFIG) and reads their readiness back from
    the works' status feedback. Capacity (when omitted) is the ManagedCluster's allocatable;
    privacyLevel, costPerCoreHour and a WAN uplink (when omitted) come from the cluster's
    ClusterClaims (privacy-level.fogfleet.io, cost-per-core-hour.fogfleet.io,
    wan-latency-millis.fogfleet.io, wan-bandwidth-mbps.fogfleet.io); the node is available while
    the ManagedCluster is (docs/multicluster.md)."""

    @property
    def privacy(self) -> int:
        """The privacy level in force (``privacyLevel``, or the tier's default)."""
        if self.privacy_level is not None:
            return self.privacy_level
        return 3 if self.tier is Tier.ROBOT else 0

    @model_validator(mode="after")
    def _robot_has_uplink(self) -> ComputeNodeSpec:
        enforce(self, self.RULES)
        refuse_duplicates([d.name for d in self.devices], "devices")
        return self


class ComputeNodeStatus(FogModel):
    """What the operator observed about the node (written by the operator)."""

    observed_generation: int | None = None
    """The metadata.generation this status describes."""
    conditions: list[Condition] = Field(default_factory=list)
    """Ready: the Kubernetes Node exists, is Ready and not cordoned."""
    allocatable_cpu: str | None = None
    """The Node's allocatable CPU as Kubernetes reports it."""
    allocatable_memory: str | None = None
    """The Node's allocatable memory as Kubernetes reports it."""
    ready: bool | None = None
    """The Node exists, is Ready and is not cordoned."""
    fleets: list[str] = Field(default_factory=list)
    """RobotFleets (namespace/name) whose plan places module instances on this node."""
    instances: int | None = None
    """Module instances those plans place here."""
    cpu_planned: str | None = None
    """CPU those instances are given, in cores (their requests = limits)."""
    cpu_others: str | None = None
    """CPU the pods fogfleet does not own request on the node (DaemonSets, other workloads):
    what fleets plan around."""
    cpu_free: str | None = None
    """Allocatable CPU left after the fleets' plans and the other pods' requests."""


class ComputeNode(FogModel):
    """A Kubernetes node as fogfleet sees it: tier, hardware type, devices, links, privacy."""

    PLURAL: ClassVar[str] = COMPUTENODES
    """The resource name in API paths (``/apis/fogfleet.io/v1alpha1/.../computenodes``)."""

    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["ComputeNode"] = "ComputeNode"
    metadata: ObjectMeta
    spec: ComputeNodeSpec
    status: ComputeNodeStatus | None = None

    @property
    def node_name(self) -> str:
        return self.spec.node_name or self.metadata.name
