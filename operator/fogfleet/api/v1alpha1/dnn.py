"""``SoftwareModule.spec.dnn``: a module whose neural network can be cut between its robot and
an off-board node, as RoboEC2 does (roboec2-dnn-offloading, Section IV; DNNSPLIT.md 3.2).

The network's *head* (the layers up to a split point) runs on the robot, its *tail* (the rest)
on the edge or cloud node the planner picks, and the tensor at the split point crosses the
link. The robot also keeps a *local model*, a lightweight network that answers alone when the
link is gone (eq. 2's action n+1). For each candidate node the split is chosen from that node's
link by RoboEC2's Spotlight Criteria (eq. 8, Algorithm 1; ``contract.dnnsplit``).

Every time is declared in milliseconds on a *reference core*, a node whose ``speedFactor`` is 1
(the time on a node is the reference time divided by its ``speedFactor``), for one frame with
one thread. One frame arrives every ``cycleTimeMillis``.

Times may also be known per hardware type (``profiles``): measured there by the operator's
profiling Job (``profiling.mode: auto``, which then measures every time and byte count instead
of the user declaring them) or declared. Where a node's hardware type has one, the planner uses
its times on that node as they are (no ``speedFactor``): the heads and the local model from the
robot's type, the tails and the whole network from the tail node's type.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from fogfleet.contract.dnnsplit import Spotlight

from .base import FogModel, Number, Quantity, parse_quantity, refuse_duplicates

__all__ = [
    "MEASURED_FIELDS",
    "Dnn",
    "DnnChoice",
    "DnnHardwareProfile",
    "DnnLocalModel",
    "DnnMeasuredSplit",
    "DnnSplitPoint",
    "Spotlight",
]

Fraction = Annotated[float, Field(ge=0, le=1)]
SplitName = Annotated[
    str, Field(min_length=1, max_length=63, pattern=r"^[a-z0-9]([-a-z0-9_.]*[a-z0-9])?$")
]


class DnnSplitPoint(FogModel):
    """One place the network can be cut (eq. 2's actions 1..n), in order from input to output."""

    name: SplitName
    """The split point's name (the layer it cuts after, e.g. bneck; the image's model files
    are named by it)."""
    head_millis: Number | None = None
    """The head's time per frame on the reference core: the layers up to this point, run on
    the robot. Measured instead with profiling.mode auto."""
    tail_millis: Number | None = None
    """The tail's time per frame on the reference core: the rest, run off board. Measured
    instead with profiling.mode auto."""
    tensor_bytes: Quantity | None = None
    """Bytes of the tensor that crosses the link at this point, per frame (eq. 4's Data^a).
    Measured instead with profiling.mode auto."""


class DnnLocalModel(FogModel):
    """The lightweight network the robot keeps (eq. 2's action n+1): it answers while the link
    is down, or when no off-board action meets the bounds."""

    name: SplitName
    """The local model's name (shown in status)."""
    robot_millis: Number | None = None
    """Its time per frame on the reference core (it runs on the robot). Measured instead with
    profiling.mode auto."""
    accuracy: Fraction
    """Its accuracy, 0-1, as its authors report it (eq. 6): below minAccuracy, it answers only
    when nothing else can."""


# what profiling measures (and the user otherwise declares), as the CEL rules name them
MEASURED_FIELDS = (
    "inputBytes",
    "outputBytes",
    "fullMillis",
    "localModel.robotMillis",
    "splitPoints[].headMillis",
    "splitPoints[].tailMillis",
    "splitPoints[].tensorBytes",
)


class DnnMeasuredSplit(FogModel):
    """One split point's times on a hardware type."""

    name: SplitName
    """The split point's name (as in splitPoints, in the same order)."""
    head_millis: Number
    """The head's time per frame on this hardware type, one thread."""
    tail_millis: Number
    """The tail's time per frame on this hardware type, one thread."""
    tensor_bytes: Annotated[int, Field(ge=1)]
    """Bytes of the tensor that crosses the link at this point, per frame."""


class DnnHardwareProfile(FogModel):
    """The network's times on one hardware type, per frame with one thread (measured by a
    profiling Job, or declared)."""

    hardware_type: str
    """The hardware type (ComputeNode spec.hardwareType)."""
    input_bytes: Annotated[int, Field(ge=1)]
    """Bytes of one input frame."""
    output_bytes: Annotated[int, Field(ge=1)]
    """Bytes of the network's answer."""
    full_millis: Number
    """The whole network's time per frame."""
    local_millis: Number
    """The local model's time per frame."""
    split_points: Annotated[list[DnnMeasuredSplit], Field(max_length=32)] = Field(
        default_factory=list
    )
    """Every split point's head and tail times and tensor bytes, in splitPoints' order."""
    frames: Annotated[int, Field(ge=0)] = 0
    """Frames timed per part (the median of them; 0: declared)."""


class Dnn(FogModel):
    """The network and the bounds every frame must meet (eq. 8: maxLatencyMillis is alpha,
    minAccuracy theta, maxRobotMillis gamma)."""

    spotlight: Spotlight = Spotlight.TIME
    """What the module cares most about (RoboEC2's spotlight, eq. 8): time (the fastest
    action), cost (the least computation on the robot that still meets maxLatencyMillis) or
    accuracy (the big model off board). Default time."""
    max_latency_millis: Number | None = None
    """Alpha: a frame's answer must come within this many milliseconds (robot computation,
    transfer both ways and off-board computation). Unset: cycleTimeMillis. At most
    cycleTimeMillis."""
    min_accuracy: Fraction = 0.0
    """Theta, 0-1: the local model runs only when its accuracy is at least this, unless no
    off-board action meets the bounds."""
    max_robot_millis: Number | None = None
    """Gamma: the most the robot may compute per frame, in milliseconds on the reference core.
    Unset: no bound."""
    input_bytes: Quantity | None = None
    """Bytes of one input frame: what crosses the link when the whole network runs off board
    (action 0). Measured instead with profiling.mode auto."""
    output_bytes: Quantity | None = None
    """Bytes of the network's answer, which comes back over the link. Measured instead with
    profiling.mode auto."""
    accuracy: Fraction
    """The big network's accuracy, 0-1 (every action that runs it, whole or split)."""
    full_millis: Number | None = None
    """The whole network's time per frame on the reference core (action 0, off board).
    Measured instead with profiling.mode auto."""
    split_points: Annotated[list[DnnSplitPoint], Field(max_length=32)] = Field(default_factory=list)
    """Where the network can be cut, from input to output. Empty: the module runs whole off
    board or falls back to the local model."""
    local_model: DnnLocalModel
    """The robot's lightweight network."""
    profiles: Annotated[list[DnnHardwareProfile], Field(max_length=64)] = Field(
        default_factory=list
    )
    """Times measured on a hardware type, one entry per type: on a node of that type the
    planner uses them as they are instead of the reference-core times. profiling.mode auto
    measures every type the module needs that has none (status.profiling.dnn) and plans with
    those; a declared entry is not measured again."""

    @model_validator(mode="after")
    def _check(self) -> Dnn:
        names = [p.name for p in self.split_points]
        refuse_duplicates(names, "splitPoints")
        if self.local_model.name in names:
            raise ValueError(
                f"localModel.name: {self.local_model.name!r} is also a split point's name"
            )
        for k, point in enumerate(self.split_points):
            if point.tensor_bytes is not None and parse_quantity(point.tensor_bytes) <= 0:
                raise ValueError(f"splitPoints[{k}].tensorBytes: must be greater than zero")
            if point.head_millis is not None and point.head_millis <= 0:
                raise ValueError(f"splitPoints[{k}].headMillis: must be greater than zero")
        for field, value in (
            ("inputBytes", self.input_bytes),
            ("outputBytes", self.output_bytes),
        ):
            if value is not None and parse_quantity(value) <= 0:
                raise ValueError(f"{field}: must be greater than zero")
        if self.full_millis is not None and self.full_millis <= 0:
            raise ValueError("fullMillis: must be greater than zero")
        robot_millis = self.local_model.robot_millis
        if robot_millis is not None and robot_millis <= 0:
            raise ValueError("localModel.robotMillis: must be greater than zero")
        if self.max_latency_millis is not None and self.max_latency_millis <= 0:
            raise ValueError("maxLatencyMillis: must be greater than zero")
        refuse_duplicates([p.hardware_type for p in self.profiles], "profiles")
        for k, prof in enumerate(self.profiles):
            got = [p.name for p in prof.split_points]
            if got != names:
                raise ValueError(
                    f"profiles[{k}].splitPoints: {got} are not splitPoints' names in order "
                    f"({names})"
                )
        return self

    def _measurable(self) -> list[tuple[str, object]]:
        """Every reference-core time and byte count (``MEASURED_FIELDS``) with its value."""
        out: list[tuple[str, object]] = [
            ("inputBytes", self.input_bytes),
            ("outputBytes", self.output_bytes),
            ("fullMillis", self.full_millis),
            ("localModel.robotMillis", self.local_model.robot_millis),
        ]
        for k, p in enumerate(self.split_points):
            out += [
                (f"splitPoints[{k}].headMillis", p.head_millis),
                (f"splitPoints[{k}].tailMillis", p.tail_millis),
                (f"splitPoints[{k}].tensorBytes", p.tensor_bytes),
            ]
        return out

    def missing(self) -> list[str]:
        """The reference-core times and byte counts not declared: without profiling they are
        all needed."""
        return [f for f, v in self._measurable() if v is None]

    def declared(self) -> list[str]:
        """The reference-core times and byte counts declared: with profiling none may be."""
        return [f for f, v in self._measurable() if v is not None]


class DnnChoice(FogModel):
    """The action RoboEC2's rule takes for a split network's instance where the plan runs its
    tail (status): the split point, full offload, or the local model."""

    action: str
    """full offload, a split point's name, or the local model's name."""
    reason: str
    """Why: its time against maxLatencyMillis, the bytes crossing the link and the link, the
    spotlight, and why the local model is out (e.g. "bneck: 63 ms <= 100 ms, 6272 B crossing
    over 20 Mbit/s, 8 ms (time spotlight); the local model is out: accuracy 0.61 <
    minAccuracy 0.8")."""
