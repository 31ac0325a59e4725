"""RobotFleet (namespaced): robots, the modules each runs, the nodes it may use, and how to plan."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, ClassVar, Literal

from pydantic import Field, model_validator

from fogfleet.api.kinds import ROBOTFLEETS

from .base import FogModel, Number, PosInt, parse_millis, refuse_duplicates
from .common import Condition, LabelSelector, Name, ObjectMeta, Tier
from .fallback import Fallback, FallbackMode
from .linkhealth import LinkHealth, RobotLinkStatus
from .objectives import DEFAULT_OBJECTIVES, ObjectiveName
from .observed import DriftSettings
from .placement import (
    PLACEMENT_LIST_LIMIT,
    CompactPlacement,
    ModulePlacement,
    PlacementEntry,
)
from .rules import CrossFieldRule, enforce

__all__ = [
    "DISCOVERY_SERVER_RMWS",
    "PLACEMENT_LIST_LIMIT",
    "ChoiceRule",
    "CompactPlacement",
    "DiscoveryRange",
    "ModuleMissStatus",
    "ModulePlacement",
    "ModuleRef",
    "ObjectiveName",  # from .objectives, the registry
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
    """nsga2 (the paper's planner), k8s-default (what kube-scheduler would do), onboard
    (everything on its robot), random, exact (a MILP over a scalarised objective)."""

    NSGA2 = "nsga2"
    K8S_DEFAULT = "k8s-default"
    ONBOARD = "onboard"
    RANDOM = "random"
    EXACT = "exact"


class ChoiceRule(StrEnum):
    """How one plan is picked from the Pareto front."""

    LEXICOGRAPHIC = "lexicographic"
    WEIGHTED = "weighted"
    KNEE = "knee"


class ObjectiveWeight(FogModel):
    """The weight of one objective in the weighted choice."""

    objective: ObjectiveName
    """The objective weighted."""
    weight: Number = 1
    """Its weight (a number or quantity; objectives are normalised over the front first)."""


class ModuleOverrides(FogModel):
    """Per-fleet changes to a module's spec (unset: the module's own value)."""

    cycle_time_millis: Number | None = None
    """Deadline of one cycle in milliseconds, for this fleet."""
    activation_percent: Annotated[int, Field(ge=1, le=100)] | None = None
    """Share of time the module is active (1-100), for this fleet."""
    replicas: PosInt | None = None
    """Replicas of a shared module, for this fleet."""
    preferred_tiers: list[Tier] | None = None
    """Tiers the module should run on when it can, for this fleet (overrides the module's
    preferredTiers and the fleet's)."""
    priority: Annotated[int, Field(ge=1, le=1000)] | None = None
    """The module's priority in this fleet (1-1000; see SoftwareModule spec.priority)."""

    @property
    def cycle_seconds(self) -> float | None:
        """``cycleTimeMillis`` in seconds; None where the module's own applies."""
        return None if self.cycle_time_millis is None else parse_millis(self.cycle_time_millis)

    @model_validator(mode="after")
    def _unique(self) -> ModuleOverrides:
        refuse_duplicates([t.value for t in self.preferred_tiers or []], "preferredTiers")
        return self


class ModuleRef(FogModel):
    """A SoftwareModule (same namespace) the fleet runs."""

    name: Name
    """The SoftwareModule's name."""
    overrides: ModuleOverrides = Field(default_factory=ModuleOverrides)
    """Per-fleet changes to the module's spec (default: none)."""


DEFAULT_CPU_LIMIT_PERCENT = 200


class SchedulerSettings(FogModel):
    """How the fleet is planned: algorithm, objectives, choice rule and NSGA-II's parameters
    (multi-robot-edge-cloud-scheduling III-C/D)."""

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "self.all(o, self.exists_one(p, p == o))",
            "objectives: each objective may be listed once",
            lambda s: len(set(s)) == len(s),
        ),
    )
    """Rules on ``objectives`` (the list itself is ``self`` in CEL)."""

    algorithm: SchedulerName = SchedulerName.NSGA2
    """The planner."""
    objectives: list[ObjectiveName] = Field(
        default_factory=lambda: list(DEFAULT_OBJECTIVES),
        min_length=1,
        max_length=len(ObjectiveName),
        description="Objectives, in priority order for the lexicographic choice. Default: "
        "missRate, missedCycles, onboard, reserve, balance. Unless cost is listed, the "
        "lexicographic choice takes the cheapest of the plans that miss alike before the "
        "other objectives, so a paid cloud takes only the overflow.",
    )
    weights: list[ObjectiveWeight] = Field(default_factory=list)
    """Weights of the weighted choice (unlisted objectives weigh 1, 0 leaves one out)."""
    choice: ChoiceRule = ChoiceRule.LEXICOGRAPHIC
    """lexicographic (objectives in order), weighted (smallest weighted worst normalised
    objective, pymoo's ASF), or knee (the front's knee point)."""
    population: Annotated[int, Field(ge=4, le=2000)] = 100
    """NSGA-II population size."""
    generations: Annotated[int, Field(ge=1, le=10000)] = 100
    """NSGA-II generations at most (convergence or the time budget may stop it earlier)."""
    stall_generations: Annotated[int, Field(ge=0, le=10000)] | None = None
    """The evolution stops once the population's best feasible plan (lexicographically, in
    the order of objectives) has not improved for this many generations, and the local
    search takes over. Unset: 10, or one per 10 genes for larger fleets. 0: run every
    generation. Reads no clock: the same seed gives the same plan."""
    mutation_percent: Annotated[int, Field(ge=0, le=100)] = 30
    """Probability, in percent, that a child is mutated."""
    seed: Annotated[int, Field(ge=0)] = 1
    """Random seed: the same inputs and seed give the same plan."""
    time_budget_millis: Annotated[int, Field(ge=100)] = 20000
    """Wall-clock budget of the search, in milliseconds (status.planningMillis): the
    evolution gets 60 % of it, the levelling and the local search until 90 %, the final
    polish until 97 %. Each is also bounded by work, so a plan the budget does not cut depends
    only on the inputs and the seed. A plan cut in its evolution only says after how many
    generations (set generations to that count to reproduce it); status.planGap tells what a
    short budget cost. The first population is never cut (about 4 s at 1000 robots)."""
    migration_margin_percent: Annotated[int, Field(ge=0, le=100)] = 5
    """A new plan replaces the running one only if it is this many percent better; keeps
    modules from moving for marginal gains."""
    cpu_limit_percent: Annotated[int, Field(ge=100, le=1000)] = DEFAULT_CPU_LIMIT_PERCENT
    """CPU limit of a planned module, in percent of the CPU its profile row needs (its
    request, or a degraded module's deadline CPU). The kernel enforces a limit per 100 ms: a
    30 Hz loop whose middleware bursts past an exact limit is stopped for the rest of the
    period and misses its next cycles. 100 gives Guaranteed pods (the paper's "with limits");
    the default 200 keeps requests (what the plan reserves) and leaves room for bursts."""
    allow_degraded: bool = True
    """When the nodes are short of CPU, run the lowest-priority modules (SoftwareModule
    spec.priority) with less CPU than their deadline needs, with their predicted misses in the
    Degraded condition, instead of refusing the fleet. false: refuse it (Ready=False)."""
    incremental: bool = True
    """Re-plan a change that touches few modules (a robot joining or leaving, a node failing,
    one module changing: at most 10% of the instances) from the running placement, with only
    those instances and 1% of the others free to move; the whole fleet is planned again
    when that result is worse than the deployed plan by the migration margin. false: plan the
    whole fleet on every change."""

    @model_validator(mode="after")
    def _unique(self) -> SchedulerSettings:
        enforce(self.objectives, self.RULES)
        refuse_duplicates([w.objective.value for w in self.weights], "weights")
        return self


DISCOVERY_SERVER_RMWS = ("rmw_fastrtps_cpp",)
"""The RMWs the discovery-server isolation works with: Fast DDS reads ROS_DISCOVERY_SERVER
(rmw_fastrtps_dynamic_cpp would too, but no image here runs it; Cyclone DDS and Zenoh ignore
it). The generic alternative (ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT with
ROS_STATIC_PEERS per robot, Jazzy and later) is not offered: only Fast DDS runs here."""


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

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "(has(self.enabled) && !self.enabled) || !has(self.rmwImplementation) || "
            f"self.rmwImplementation in {list(DISCOVERY_SERVER_RMWS)!r}",
            "rmwImplementation: the robots are isolated by Fast DDS discovery servers "
            "(ROS_DISCOVERY_SERVER), which other RMWs ignore, so their robots would see each "
            f"other; use {' or '.join(DISCOVERY_SERVER_RMWS)} (or enabled: false and wire "
            "ROS yourself)",
            lambda s: not s.enabled or s.rmw_implementation in DISCOVERY_SERVER_RMWS,
        ),
    )

    enabled: bool = Field(default=True, description="Inject the ROS 2 wiring into the modules.")
    rmw_implementation: Annotated[str, Field(min_length=1)] = Field(
        default="rmw_fastrtps_cpp",
        description="RMW_IMPLEMENTATION of every module. With enabled (the discovery-server "
        "isolation) only rmw_fastrtps_cpp: the one RMW that honours ROS_DISCOVERY_SERVER and "
        "that the workload image runs.",
    )
    discovery_range: DiscoveryRange = DiscoveryRange.SUBNET
    """ROS_AUTOMATIC_DISCOVERY_RANGE of every module and discovery server."""
    domain_id: Annotated[int, Field(ge=0, le=232)] = Field(
        default=0, description="ROS_DOMAIN_ID of the whole fleet."
    )
    discovery_server_image: Annotated[str, Field(min_length=1)] = Field(
        default="ghcr.io/fogfleet/ros2-module:0.1.0",
        description="Image with `python -m fogfleet.workload discovery-server`.",
    )
    discovery_server_port: Annotated[int, Field(ge=1024, le=65535)] = 11811
    """UDP port of each robot's discovery server."""

    @model_validator(mode="after")
    def _check(self) -> RosSettings:
        enforce(self, self.RULES)
        return self


class RobotFleetSpec(FogModel):
    """The robots, the modules each runs, the edge/cloud nodes it may use, and how to plan."""

    RULES: ClassVar[tuple[CrossFieldRule, ...]] = (
        CrossFieldRule(
            "(has(self.robots) && size(self.robots) > 0) || has(self.robotSelector)",
            "robots: list at least one robot or set robotSelector",
            lambda s: bool(s.robots) or s.robot_selector is not None,
        ),
        CrossFieldRule(
            "!has(self.fallback) || !has(self.fallback.mode) || self.fallback.mode != 'variant'",
            "fallback.mode: variant names one module's variant: set it on that SoftwareModule "
            "(the fleet's default is none or onboard)",
            lambda s: s.fallback.mode is not FallbackMode.VARIANT,
        ),
    )

    robots: list[Name] = Field(default_factory=list, description="Robot ComputeNode names.")
    robot_selector: LabelSelector | None = None
    """Robot ComputeNodes chosen by label (with or instead of robots)."""
    modules: list[ModuleRef] = Field(min_length=1)
    """The SoftwareModules every robot runs (shared modules: once for the fleet)."""
    nodes: list[Name] = Field(default_factory=list, description="Edge/cloud ComputeNode names.")
    node_selector: LabelSelector | None = None
    """Edge/cloud ComputeNodes chosen by label (with nodes; neither: every edge/cloud node)."""
    scheduler: SchedulerSettings = Field(default_factory=SchedulerSettings)
    """How to plan (default: NSGA-II, lexicographic choice with missRate first)."""
    ros: RosSettings = Field(default_factory=RosSettings)
    """ROS 2 wiring: a discovery server per robot, RMW and domain (default: enabled)."""
    paused: bool = False
    """Keep the running placement; plan nothing until unpaused."""
    preferred_tiers: list[Tier] = Field(default_factory=list)
    """Tiers the fleet's modules should run on when they can, for modules that name none
    (e.g. [robot, edge]: the cloud only for overflow). Empty: no preference."""
    fallback: Fallback = Field(default_factory=Fallback)
    """Default fallback of the fleet's modules that set none (mode none unless given). With
    onboard, a per-robot module that publishes topics keeps a standby on its robot while it
    runs elsewhere; shared modules and modules without outputs have none."""
    link_health: LinkHealth = Field(default_factory=LinkHealth)
    """How the robots' links are measured and re-planned around (needs the operator's
    Prometheus)."""
    drift: DriftSettings = Field(default_factory=DriftSettings)
    """When measured misses above the plan's prediction re-plan the fleet with learnt
    profiles (needs the operator's Prometheus)."""

    @model_validator(mode="after")
    def _check(self) -> RobotFleetSpec:
        enforce(self, self.RULES)
        refuse_duplicates(self.robots, "robots")
        refuse_duplicates(self.nodes, "nodes")
        refuse_duplicates([m.name for m in self.modules], "modules")
        refuse_duplicates([t.value for t in self.preferred_tiers], "preferredTiers")
        return self


class ObjectiveValue(FogModel):
    """One objective of the deployed plan."""

    name: str
    """The objective (F1-F4 and the extensions)."""
    value: float
    """Its value (lower is better)."""


class PlanGapStatus(FogModel):
    """How far the search came from the best any plan could do, in one number: the best
    scalarised S it found (the weighted sum the exact scheduler minimises: 100*missRate +
    missedCycles + onboard per robot + reserve [+ cost]) against a lower bound on every
    plan's S, and the deployed plan's S beside it."""

    percent: float
    """(best S found - bound) / bound in percent: an upper bound on how far the search's best
    plan is from the optimum of S (part of it may be the bound's own)."""
    value: float
    """The best S the search found (its Pareto front, or the deployed plan)."""
    bound: float
    """The lower bound on every plan's S."""
    bound_kind: Literal["robot", "lp"]
    """robot: each robot's instances kept whole (a Lagrangian bound); lp: the LP
    relaxation's optimum (solved for fleets of up to 5000 instance-node pairs)."""
    deployed_percent: float
    """The deployed plan's gap. It is chosen from the front by spec.scheduler.choice, not by
    S (the default lexicographic rule puts misses first), so this also holds what that rule
    traded for the fleet's own order of objectives."""
    deployed_value: float
    """The deployed plan's S."""
    time_budget_reached: bool = False
    """The planning budget (spec.scheduler.timeBudgetMillis) cut the search: a larger budget
    may lower the gap."""


class StandbyTakeoverStatus(FogModel):
    """What one module's on-board standby did: its takeovers from the silent remote instance,
    read from the standby's own metrics (fogfleet_fallback_takeovers_total,
    fogfleet_fallback_takeover_gap_seconds, fogfleet_fallback_last_takeover_timestamp_seconds,
    fogfleet_fallback_active) through the operator's Prometheus, every link measurement."""

    module: str
    """The SoftwareModule."""
    count: int = 0
    """Takeovers the operator has seen since the fleet's links are monitored (a restarted
    standby's counter is counted on from where it was). A standby on a cut-off robot is not
    scraped: its takeover is counted when the link is back."""
    last_gap_seconds: float | None = None
    """The last takeover's gap: seconds from the remote's last output to the standby's first
    own output (what the robot's topic went without)."""
    last_takeover_time: str | None = None
    """When the last takeover happened (RFC 3339), by the standby's clock; from a workload that
    does not export it, when the operator first saw it (after a cut: when the link returned)."""
    active: bool = False
    """Whether the standby computes the module's outputs on board now."""


class RobotFallbackStatus(FogModel):
    """What losing its link costs one robot under the deployed plan (fleets with fallbacks)."""

    robot: str
    """The robot's ComputeNode."""
    reserved_cpu: str
    """CPU the robot holds for its modules' on-board fallbacks, whatever the plan."""
    standbys: list[str] = Field(default_factory=list)
    """Offloaded modules whose standby on the robot takes over."""
    stopped: list[str] = Field(default_factory=list)
    """Offloaded modules without a fallback: they stop while the link is down."""
    predicted_miss_rate: float
    """Predicted fraction of the robot's cycles missed while its link is down (0-1)."""
    takeovers: list[StandbyTakeoverStatus] | None = None
    """Per module with a standby on the robot (and any other whose standby took over): what
    the standby did. Unset while the fleet's links are not monitored (spec.linkHealth, the
    operator's Prometheus: the Monitored condition)."""


class ModuleMissStatus(FogModel):
    """One module's cycles as measured against the deployed plan's prediction."""

    module: str
    """The SoftwareModule."""
    predicted_miss_rate: float
    """What the plan predicts (0-1)."""
    drift_margin: float | None = None
    """How much more than predicted it may miss before it drifts (0-1): its real-time class's
    share of spec.drift.marginPercent (a hundredth for hard real-time or safety-critical, all
    of it for soft real-time, twice it for the rest)."""
    measured_miss_rate: float | None = None
    """What its pods' counters show over spec.drift.windowSeconds (0-1)."""
    cycles: float = 0
    """Cycles measured in the window."""
    drifting_since: str | None = None
    """Since when it misses more than predicted by more than driftMargin (RFC 3339)."""
    cpu_needed: str | None = None
    """For a drifting module that cannot leave its robot (hard real-time, safety-critical or
    pinned by its requirements): the CPU its measured execution time needs to finish within
    its cycle on the robot that is shortest of it (95th-percentile execution time x the CPU
    limit it ran with / its cycle time)."""
    cpu_short: str | None = None
    """How much CPU that robot lacks for it: cpuNeeded less the most the robot can guarantee
    it (its request and the robot's unreserved CPU). Unset when the robot has enough."""


class SharedNodeStatus(FogModel):
    """A node the fleet shares with other tenants (other fleets, pods fogfleet does not own)."""

    node: str
    """The Kubernetes Node."""
    held_cpu: str
    """CPU the others hold there (their plans or pods' requests), which this fleet planned
    around."""
    left_cpu: str
    """CPU left on the node after the others and this fleet's plan."""
    held_by: list[str] = Field(default_factory=list)
    """Who holds it: other RobotFleets, and the namespaces of other pods."""


class RobotFleetStatus(FogModel):
    """The deployed plan and how its rollout stands (written by the operator)."""

    observed_generation: int | None = None
    """The metadata.generation this status describes."""
    conditions: list[Condition] = Field(default_factory=list)
    """Ready (every instance runs where planned), Scheduled (planned or bound), Degraded
    (instances moving or stranded on an unavailable node, a robot's link lost or measured
    worse than declared, a standby computing on board), Drift (modules missing more cycles
    than the plan predicted; for a module that cannot leave its robot, how much CPU the
    robot is short for it) and Monitored (whether the operator's Prometheus feeds SLO
    scaling, link health, learnt profiles and drift detection: True with reason Prometheus;
    False with NoPrometheus when the operator has none, all four are then off and
    measured/measuredMiss stay empty, set scaling.prometheusUrl in the Helm chart or
    FOGFLEET_PROMETHEUS_URL; False with PrometheusUnreachable while its queries fail)."""
    scheduler: str | None = None
    """The algorithm that made the plan."""
    placement: list[PlacementEntry] = Field(default_factory=list)
    """Where every module instance runs, for fleets of up to 1000 instances. A larger fleet
    lists none here (the object would approach etcd's 1.5 MiB limit): placementCompact holds
    the same facts in a few bytes per instance."""
    placement_compact: CompactPlacement | None = None
    """Where every module instance runs, for fleets of more than 1000 instances (unset for
    smaller ones): the robots and nodes once each, then per module one robot, replica, node
    and CPU per instance. `kubectl fogfleet` reads it; people read placementByModule, or an
    instance's node from its pods (`kubectl get pods -l fogfleet.io/fleet=NAME -o wide`)."""
    placement_by_module: list[ModulePlacement] = Field(default_factory=list)
    """Per module, how many of its instances run on robots, edge nodes and in the cloud."""
    objectives: list[ObjectiveValue] = Field(default_factory=list)
    """The deployed plan's objective values."""
    predicted_miss_rate: float | None = None
    """Predicted fraction of missed cycles of the deployed plan (0-1)."""
    predicted_miss: str | None = None
    """predictedMissRate as people read it, a percentage ("0.007%"; kubectl's MISS column),
    in the format of the CLI and the Events."""
    measured_miss_rate: float | None = None
    """Measured fraction of missed cycles of the fleet's modules (0-1): their missed cycles
    over their cycles in status.measured (each module weighed by its cycles), over
    spec.drift.windowSeconds since the last plan. Unset until cycles are measured (never 0 for
    "not measured"): measuring needs the operator's Prometheus (the Monitored condition)."""
    measured_miss: str | None = None
    """measuredMissRate as people read it, in predictedMiss's format (kubectl's MEASURED
    column, beside MISS): where it is far above MISS, the prediction is wrong (see the Drift
    condition)."""
    modules_placed: int | None = None
    """Instances placed."""
    modules_total: int | None = None
    """Instances the fleet needs."""
    split: str | None = None
    """Instances on robots/edge/cloud, as "3/2/0"."""
    planning_millis: int | None = None
    """How long planning took, in milliseconds."""
    plan_gap: PlanGapStatus | None = None
    """The deployed plan's scalarised S against a lower bound on any plan's (unset for a
    degraded plan, and for an incremental re-plan of a fleet of over 250000 instance-node
    pairs, whose bound would take longer than the re-plan)."""
    choice_reason: str | None = None
    """Why this plan was chosen from the Pareto front."""
    migrations: int | None = None
    """Instances the last plan moved."""
    last_plan_time: str | None = None
    """When the fleet was last planned (RFC 3339)."""
    fallbacks: list[RobotFallbackStatus] = Field(default_factory=list)
    """Per robot with offloaded modules, in a fleet with on-board fallbacks: its reserve and
    what a lost link leaves of it."""
    links: list[RobotLinkStatus] = Field(default_factory=list)
    """Per robot, its link as measured (fleets whose links are monitored)."""
    measured: list[ModuleMissStatus] = Field(default_factory=list)
    """Per module, its measured miss rate against the plan's prediction (spec.drift)."""
    shared_nodes: list[SharedNodeStatus] = Field(default_factory=list)
    """The nodes the fleet shares with other tenants: what they hold, what is left. The plan
    uses only what is left."""


class RobotFleet(FogModel):
    """A robot fleet: its robots, their modules, the nodes they may use, and how to plan."""

    PLURAL: ClassVar[str] = ROBOTFLEETS
    """The resource name in API paths (``/apis/fogfleet.io/v1alpha1/.../robotfleets``)."""

    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["RobotFleet"] = "RobotFleet"
    metadata: ObjectMeta
    spec: RobotFleetSpec
    status: RobotFleetStatus | None = None
