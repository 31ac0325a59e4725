"""ComputeNode (cluster-scoped): a Kubernetes node as fogfleet sees it.

A robot's on-board computer, an edge server or a cloud VM. The hardware type keys the modules'
execution-time profiles (multi-robot-edge-cloud-scheduling III-E, Fig. 3); devices carry the
MBSE deployment constraints (cloud-native-fog-robotics-mbse, OCL); privacy level follows
tinyKube; power figures follow fog-iot-resource-optimization (battery model).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import Field, model_validator

from .base import FogModel, NonNegInt, Quantity
from .common import Condition, Name, ObjectMeta, Tier

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
    type: DeviceType


class NodeResources(FogModel):
    cpu: Quantity
    memory: Quantity
    gpu: NonNegInt = 0


class ReservedResources(FogModel):
    cpu: Quantity = 0
    memory: Quantity = 0


class NetworkLink(FogModel):
    """The node's uplink. A robot reaches an edge node over its own link plus the edge node's.

    Latency and jitter in milliseconds, bandwidth in megabit/s, loss in percent; all quantity
    strings ("2.5") or integers.
    """

    type: LinkType
    latency_millis: Quantity
    jitter_millis: Quantity = 0
    bandwidth_mbps: Quantity
    loss_percent: Quantity = 0


class PowerModel(FogModel):
    """Robot energy model (fog-iot-resource-optimization): idle + per busy core + radio."""

    battery_watt_hours: Quantity
    idle_watts: Quantity = 0
    per_core_watts: Quantity = 0
    radio_watts_per_mbps: Quantity = 0


class ComputeNodeSpec(FogModel):
    node_name: Name | None = Field(
        default=None, description="The Kubernetes Node this describes (default: metadata.name)."
    )
    tier: Tier
    hardware_type: Annotated[str, Field(min_length=1, max_length=63)]
    capacity: NodeResources | None = Field(
        default=None,
        description="Allocatable resources. The operator reads them from the Node when omitted.",
    )
    reserved: ReservedResources = Field(default_factory=ReservedResources)
    speed_factor: Quantity = Field(
        default=1,
        description="Relative CPU speed, used only when no profile names this hardware type.",
    )
    devices: list[Device] = Field(default_factory=list)
    realtime_kernel: bool = False
    privacy_level: Annotated[int, Field(ge=0, le=3)] = 0
    cost_per_core_hour: Quantity = 0
    power: PowerModel | None = None
    network: list[NetworkLink] = Field(default_factory=list, max_length=8)

    @model_validator(mode="after")
    def _robot_has_uplink(self) -> ComputeNodeSpec:
        if self.tier is not Tier.ROBOT and self.power is not None:
            raise ValueError("power: only robot nodes have a battery model")
        return self


class ComputeNodeStatus(FogModel):
    observed_generation: int | None = None
    conditions: list[Condition] = Field(default_factory=list)
    allocatable_cpu: str | None = None
    allocatable_memory: str | None = None
    ready: bool | None = None


class ComputeNode(FogModel):
    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["ComputeNode"] = "ComputeNode"
    metadata: ObjectMeta
    spec: ComputeNodeSpec
    status: ComputeNodeStatus | None = None

    @property
    def node_name(self) -> str:
        return self.spec.node_name or self.metadata.name
