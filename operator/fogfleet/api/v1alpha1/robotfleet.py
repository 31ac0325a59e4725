"""RobotFleet (namespaced): robots, the modules each runs, the nodes it may use, and how to plan."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import Field, model_validator

from .base import FogModel, PosInt, Quantity
from .common import Condition, LabelSelector, Name, ObjectMeta

__all__ = [
    "ChoiceRule",
    "DiscoveryRange",
    "ModuleRef",
    "ObjectiveName",
    "ObjectiveValue",
    "ObjectiveWeight",
    "PlacementEntry",
    "RobotFleet",
    "RobotFleetSpec",
    "RobotFleetStatus",
    "RosSettings",
    "SchedulerName",
    "SchedulerSettings",
]


class SchedulerName(StrEnum):
    NSGA2 = "nsga2"
    K8S_DEFAULT = "k8s-default"
    ONBOARD = "onboard"
    RANDOM = "random"
    EXACT = "exact"


class ObjectiveName(StrEnum):
    """F1-F4 of multi-robot-edge-cloud-scheduling (eq. 1-6) plus the extensions."""

    ONBOARD = "onboard"  # F1, eq. 1
    RESERVE = "reserve"  # F2, eq. 2
    BALANCE = "balance"  # F3, eq. 3
    MISSED_CYCLES = "missedCycles"  # F4, eq. 6
    MISS_RATE = "missRate"  # predicted fraction of missed cycles
    COST = "cost"
    ENERGY = "energy"


class ChoiceRule(StrEnum):
    LEXICOGRAPHIC = "lexicographic"
    WEIGHTED = "weighted"
    KNEE = "knee"


class ObjectiveWeight(FogModel):
    objective: ObjectiveName
    weight: Quantity = 1


class ModuleOverrides(FogModel):
    cycle_time_millis: Quantity | None = None
    activation_percent: Annotated[int, Field(ge=1, le=100)] | None = None
    replicas: PosInt | None = None


class ModuleRef(FogModel):
    name: Name
    overrides: ModuleOverrides = Field(default_factory=ModuleOverrides)


class SchedulerSettings(FogModel):
    algorithm: SchedulerName = SchedulerName.NSGA2
    objectives: list[ObjectiveName] = Field(
        default_factory=lambda: [
            ObjectiveName.MISS_RATE,
            ObjectiveName.MISSED_CYCLES,
            ObjectiveName.ONBOARD,
            ObjectiveName.RESERVE,
            ObjectiveName.BALANCE,
        ],
        min_length=1,
        max_length=len(ObjectiveName),
        description="Objectives, in priority order for the lexicographic choice.",
    )
    weights: list[ObjectiveWeight] = Field(default_factory=list)
    choice: ChoiceRule = ChoiceRule.LEXICOGRAPHIC
    population: Annotated[int, Field(ge=4, le=2000)] = 100
    generations: Annotated[int, Field(ge=1, le=10000)] = 100
    mutation_percent: Annotated[int, Field(ge=0, le=100)] = 30
    seed: Annotated[int, Field(ge=0)] = 1
    time_budget_millis: Annotated[int, Field(ge=100)] = 20000
    migration_margin_percent: Annotated[int, Field(ge=0, le=100)] = 5

    @model_validator(mode="after")
    def _unique(self) -> SchedulerSettings:
        if len(set(self.objectives)) != len(self.objectives):
            raise ValueError("objectives: each objective may be listed once")
        return self


class DiscoveryRange(StrEnum):
    """ROS_AUTOMATIC_DISCOVERY_RANGE of every module (ROS 2 Jazzy and later)."""

    SUBNET = "SUBNET"
    LOCALHOST = "LOCALHOST"
    OFF = "OFF"
    SYSTEM_DEFAULT = "SYSTEM_DEFAULT"


class RosSettings(FogModel):
    """How the operator wires the fleet's ROS 2 modules together.

    Isolation and discovery: one Fast DDS discovery server per robot, on that robot's own
    computer, behind a ClusterIP Service; every module of the robot is its client
    (``ROS_DISCOVERY_SERVER``) wherever it runs, so an offloaded module still finds its
    robot's topics, and a module never discovers another robot's modules (multicast
    discovery, which most pod networks drop anyway, is not used). Shared modules are clients
    of every robot's server. Unmodified nodes with absolute topic names stay isolated.
    """

    enabled: bool = Field(default=True, description="Inject the ROS 2 wiring into the modules.")
    rmw_implementation: Annotated[str, Field(min_length=1)] = Field(
        default="rmw_fastrtps_cpp", description="RMW_IMPLEMENTATION of every module."
    )
    discovery_range: DiscoveryRange = DiscoveryRange.SUBNET
    domain_id: Annotated[int, Field(ge=0, le=232)] = Field(
        default=0, description="ROS_DOMAIN_ID of the whole fleet."
    )
    discovery_server_image: Annotated[str, Field(min_length=1)] = Field(
        default="ghcr.io/fogfleet/ros2-module:0.1.0",
        description="Image with `python -m fogfleet.workload discovery-server`.",
    )
    discovery_server_port: Annotated[int, Field(ge=1024, le=65535)] = 11811


class RobotFleetSpec(FogModel):
    robots: list[Name] = Field(default_factory=list, description="Robot ComputeNode names.")
    robot_selector: LabelSelector | None = None
    modules: list[ModuleRef] = Field(min_length=1)
    nodes: list[Name] = Field(default_factory=list, description="Edge/cloud ComputeNode names.")
    node_selector: LabelSelector | None = None
    scheduler: SchedulerSettings = Field(default_factory=SchedulerSettings)
    ros: RosSettings = Field(default_factory=RosSettings)
    paused: bool = False

    @model_validator(mode="after")
    def _check(self) -> RobotFleetSpec:
        if not self.robots and self.robot_selector is None:
            raise ValueError("robots: list at least one robot or set robotSelector")
        names = [m.name for m in self.modules]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"modules: {', '.join(dup)} listed more than once")
        return self


class PlacementEntry(FogModel):
    robot: str
    module: str
    node: str
    tier: str
    cpu: str | None = None
    replica: int | None = None


class ObjectiveValue(FogModel):
    name: str
    value: float


class RobotFleetStatus(FogModel):
    observed_generation: int | None = None
    conditions: list[Condition] = Field(default_factory=list)
    scheduler: str | None = None
    placement: list[PlacementEntry] = Field(default_factory=list)
    objectives: list[ObjectiveValue] = Field(default_factory=list)
    predicted_miss_rate: float | None = None
    modules_placed: int | None = None
    modules_total: int | None = None
    split: str | None = Field(default=None, description="on-board/edge/cloud instance counts")
    planning_millis: int | None = None
    choice_reason: str | None = None
    migrations: int | None = None
    last_plan_time: str | None = None


class RobotFleet(FogModel):
    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["RobotFleet"] = "RobotFleet"
    metadata: ObjectMeta
    spec: RobotFleetSpec
    status: RobotFleetStatus | None = None
