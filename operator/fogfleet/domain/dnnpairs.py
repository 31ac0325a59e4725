"""What a split-network module (``SoftwareModule.spec.dnn``) gets on one node: the planner's pair
for its tail off board and for its local model at home (DNNSPLIT.md 3.2), and what its robot
holds whatever the plan (the head and the local model).

The instance's gene is where its tail runs. On each edge or cloud node the split is resolved
from that node's link with RoboEC2's rule (``contract.dnnsplit.choose``;
roboec2-dnn-offloading eq. 8, Algorithm 1): the chosen action fixes the tail's time there, the
bytes that cross, and the frame's time outside the tail (the head on the robot and the
transfer both ways), which the pair carries as its transfer time so that eq. 4's
``exe + net`` is the action's ``Time(a)``.
A node over whose link no off-board action meets the bounds is refused with the rule's reason.
On its own robot the instance runs the local model alone (action n+1): allowed when the local
model meets the bounds, or when no off-board node is left (Algorithm 1: "take the action n+1").

Times come from the network's profile on a node's hardware type where it has one
(``spec.dnn.profiles``, or what profiling measured there: ``domain.profiling.with_profiled``),
as measured; else from the declared reference-core times divided by the node's ``speedFactor``
(``network_on``): the heads and the local model from the robot's type, the tails and the whole
network from the tail node's.

A network runs on one thread: under a CPU limit ``c`` below one core the kernel's quota lets
it run ``c`` of every period, so a frame takes ``time / c``; from one core on, ``time``. Its
profile rows (Fig. 3) are these, on the steps of ``CPU_STEPS``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from fogfleet.api.v1alpha1.base import parse_quantity
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.dnn import Dnn, DnnHardwareProfile
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.contract.dnnsplit import Action, Choice, DnnSplit, SplitPoint, actions, choose

from .network import Link
from .problem import EXEC_SHARE_OF_CYCLE, NodeInfo, Problem
from .rows import ProfileRow

__all__ = [
    "CPU_STEPS",
    "REFERENCE",
    "NodeKind",
    "OnNodes",
    "alpha_s",
    "dnn_rows",
    "full_seconds",
    "kind_of",
    "local_pair_rows",
    "model_of",
    "network_on",
    "off_board",
    "planned_choice",
    "resolve",
    "robot_row",
    "tail_rows",
]

CPU_STEPS = (0.1, 0.2, 0.25, 0.5, 0.75, 1.0)  # cores a network's pod may be given
BITS_PER_BYTE = 8


class NodeKind(NamedTuple):
    """What a node's times depend on: its hardware type (a profile measured there) and its
    speed (declared reference-core times divided by it)."""

    hardware_type: str
    speed_factor: float


REFERENCE = NodeKind("", 1.0)  # the reference core: declared times as they are


def kind_of(node: ComputeNode | NodeInfo) -> NodeKind:
    """``node``'s hardware type and speed factor."""
    if isinstance(node, NodeInfo):
        return NodeKind(node.hardware_type, node.speed_factor)
    return NodeKind(node.spec.hardware_type, float(parse_quantity(node.spec.speed_factor)))


def alpha_s(dnn: Dnn, cycle_s: float) -> float:
    """Alpha in seconds: ``maxLatencyMillis``, else the module's cycle."""
    return cycle_s if dnn.max_latency_millis is None else dnn.max_latency_millis / 1e3


def _network(
    dnn: Dnn,
    cycle_s: float,
    io_bytes: tuple[int, int],
    full_s: float,
    points: tuple[SplitPoint, ...],
    local_s: float,
) -> DnnSplit:
    """The rule's model: ``dnn``'s bounds and accuracies (no node changes them) with these
    times (seconds) and ``io_bytes`` (input, output)."""
    return DnnSplit(
        spotlight=dnn.spotlight,
        max_latency_s=alpha_s(dnn, cycle_s),
        min_accuracy=dnn.min_accuracy,
        max_robot_s=None if dnn.max_robot_millis is None else dnn.max_robot_millis / 1e3,
        input_bytes=io_bytes[0],
        output_bytes=io_bytes[1],
        accuracy=dnn.accuracy,
        full_s=full_s,
        split_points=points,
        local_name=dnn.local_model.name,
        local_s=local_s,
        local_accuracy=dnn.local_model.accuracy,
    )


def model_of(dnn: Dnn, cycle_s: float) -> DnnSplit:
    """``SoftwareModule.spec.dnn`` in seconds on the reference core (alpha defaults to the
    module's cycle). ValueError when a time is not declared (profiling measures it)."""
    missing = dnn.missing()
    if missing:
        raise ValueError(f"dnn: {', '.join(missing)} not declared (profiling measures them)")
    return _network(
        dnn,
        cycle_s,
        (int(parse_quantity(dnn.input_bytes or 0)), int(parse_quantity(dnn.output_bytes or 0))),
        (dnn.full_millis or 0.0) / 1e3,
        tuple(
            SplitPoint(
                p.name,
                (p.head_millis or 0.0) / 1e3,
                (p.tail_millis or 0.0) / 1e3,
                int(parse_quantity(p.tensor_bytes or 0)),
            )
            for p in dnn.split_points
        ),
        (dnn.local_model.robot_millis or 0.0) / 1e3,
    )


def _measured(profile: DnnHardwareProfile, dnn: Dnn, cycle_s: float) -> DnnSplit:
    """A profile measured on one hardware type, as the rule's model (seconds there)."""
    return _network(
        dnn,
        cycle_s,
        (profile.input_bytes, profile.output_bytes),
        profile.full_millis / 1e3,
        tuple(
            SplitPoint(p.name, p.head_millis / 1e3, p.tail_millis / 1e3, p.tensor_bytes)
            for p in profile.split_points
        ),
        profile.local_millis / 1e3,
    )


@dataclass(frozen=True)
class OnNodes:
    """A split network for one robot and one tail node: the rule's model with the heads and the
    local model as the robot's side states them and the tails and the whole network as the
    tail node's does, and each side's time per second of those (1 where measured there, else
    1 / speedFactor). ``actions(model, link, robot_factor, tail_factor)`` is then the rule's
    input (``contract.dnnsplit``)."""

    model: DnnSplit
    robot_factor: float
    tail_factor: float
    measured: bool  # either side's times were measured on its hardware type


def _side(dnn: Dnn, kind: NodeKind, cycle_s: float) -> tuple[DnnSplit, float, bool] | None:
    """One side's model and factor: measured on its type, else declared (None: neither)."""
    profile = next((p for p in dnn.profiles if p.hardware_type == kind.hardware_type), None)
    if profile is not None:
        return _measured(profile, dnn, cycle_s), 1.0, True
    if dnn.missing():
        return None
    return model_of(dnn, cycle_s), 1.0 / max(kind.speed_factor, 1e-6), False


def network_on(dnn: Dnn, cycle_s: float, robot: NodeKind, tail: NodeKind) -> OnNodes | str:
    """``dnn`` with its head on a ``robot`` and its tail on a ``tail`` node (see ``OnNodes``), or
    which hardware type has no times yet (profiling measures them there first)."""
    r = _side(dnn, robot, cycle_s)
    t = r if tail == robot else _side(dnn, tail, cycle_s)
    if r is None or t is None:
        lacking = sorted({k.hardware_type for k, v in ((robot, r), (tail, t)) if v is None})
        return (
            f"no times of its network for hardware type {', '.join(map(repr, lacking))} "
            "(profiling.mode auto: the operator profiles it there first)"
        )
    (rm, rf, r_meas), (tm, tf, t_meas) = r, t
    points = tuple(
        SplitPoint(h.name, h.head_s, tl.tail_s, h.tensor_bytes)
        for h, tl in zip(rm.split_points, tm.split_points, strict=True)
    )
    model = _network(dnn, cycle_s, (rm.input_bytes, rm.output_bytes), tm.full_s, points, rm.local_s)
    return OnNodes(model, rf, tf, r_meas or t_meas)


def full_seconds(dnn: Dnn, kind: NodeKind) -> float | None:
    """The whole network's time per frame on a node of ``kind`` (None: not known there)."""
    on = network_on(dnn, 1.0, kind, kind)
    return None if isinstance(on, str) else on.model.full_s * on.tail_factor


def dnn_rows(time_s: float, cap_cores: float) -> list[ProfileRow]:
    """A one-thread network of ``time_s`` per frame at one core, as rows at ``CPU_STEPS`` that
    fit a node of ``cap_cores`` (smallest CPU first)."""
    return [ProfileRow(c, time_s / min(c, 1.0), 0.0) for c in CPU_STEPS if c <= cap_cores + 1e-9]


def resolve(
    module: SoftwareModule, cycle_s: float, robot: NodeKind, node: NodeKind, link: Link
) -> tuple[OnNodes, Choice] | str:
    """The rule's choice for ``module``'s tail on a ``node`` over ``link``, with the network
    there (or which hardware type has no times yet)."""
    assert module.spec.dnn is not None
    on = network_on(module.spec.dnn, cycle_s, robot, node)
    if isinstance(on, str):
        return on
    return on, choose(on.model, actions(on.model, link, on.robot_factor, on.tail_factor))


def tail_rows(on: OnNodes, action: Action, cap_cores: float) -> list[ProfileRow]:
    """The rows of the tail ``action`` leaves to the tail node (the whole network for action 0)."""
    return dnn_rows(_tail_s(on.model, action) * on.tail_factor, cap_cores)


def _tail_s(model: DnnSplit, action: Action) -> float:
    """What ``action`` leaves off board: the whole network for action 0, else its split's tail
    (seconds as ``model`` states them)."""
    return model.full_s if action.index == 0 else model.split_points[action.index - 1].tail_s


def off_board(
    module: SoftwareModule, cycle_s: float, robot: NodeKind, node: NodeKind, link: Link
) -> tuple[OnNodes, Choice, float, float, float] | str:
    """The tail on a ``node``: (the network there, the choice, the time outside the tail, its
    jitter, bit/s crossing), or why the node is refused (no times there yet, or no off-board
    action meets the bounds over this link)."""
    got = resolve(module, cycle_s, robot, node, link)
    if isinstance(got, str):
        return got
    on, choice = got
    action = choice.action
    if not action.offloaded:
        why = "; ".join(f"{a.name}: {w}" for a, w in choice.dropped if a.offloaded)
        return f"no part of its network may run there over this link ({why})"
    outside = action.time_s - _tail_s(on.model, action) * on.tail_factor
    crossing = (action.crossing_bytes + on.model.output_bytes) * BITS_PER_BYTE / cycle_s
    return on, choice, outside, link.jitter * math.sqrt(2), crossing


def local_pair_rows(
    module: SoftwareModule, cycle_s: float, robot: NodeKind, cap_cores: float, alone: bool
) -> list[ProfileRow] | str:
    """The local model's rows on its robot (action n+1), or why it may not answer alone there:
    no times on the robot's type yet, or below minAccuracy or over maxRobotMillis while an
    off-board node is left (``alone``: none)."""
    assert module.spec.dnn is not None
    on = network_on(module.spec.dnn, cycle_s, robot, robot)
    if isinstance(on, str):
        return on
    model = on.model
    local_s = model.local_s * on.robot_factor
    if not alone:
        if model.local_accuracy < model.min_accuracy:
            return (
                f"its local model {model.local_name} (accuracy {model.local_accuracy:g}) is "
                f"below minAccuracy {model.min_accuracy:g} and an off-board node is left"
            )
        if model.max_robot_s is not None and local_s > model.max_robot_s:
            return f"its local model {model.local_name} is over maxRobotMillis on this robot"
    return dnn_rows(local_s, cap_cores)


def robot_row(
    module: SoftwareModule, cycle_s: float, robot: NodeKind, cap_cores: float
) -> ProfileRow | None:
    """What the robot holds for the module wherever its tail runs: the head of the slowest
    split point or the local model, whichever takes longer (both stay on the robot; the local
    model answers the moment the link fails), at the smallest ``CPU_STEPS`` that keeps a frame
    within ``EXEC_SHARE_OF_CYCLE`` of alpha. It counts every split point's head, not only the
    planned one's: the robot applies the rule per frame from the link it measures (RoboEC2
    decides per frame), so a link that slows may move it to any split. None: no step fits, or
    no times on the robot's type yet."""
    assert module.spec.dnn is not None
    on = network_on(module.spec.dnn, cycle_s, robot, robot)
    if isinstance(on, str):
        return None
    model = on.model
    slowest = max([model.local_s, *(p.head_s for p in model.split_points)])
    rows = dnn_rows(slowest * on.robot_factor, cap_cores)
    if not rows:
        return None
    fit = [r for r in rows if r.mean <= EXEC_SHARE_OF_CYCLE * model.max_latency_s]
    return fit[0] if fit else rows[-1]


def planned_choice(problem: Problem, i: int, j: int) -> Choice | None:
    """The rule's choice for instance ``i`` with its tail on node ``j``, as the plan's build
    resolved it, its reason naming the link (None: ``i`` is not a split network's, or may not
    run on ``j``). On its own robot the local model answers alone."""
    inst = problem.instances[i]
    dnn = (problem.split_models or {}).get(inst.module)
    index = -1 if problem.dnn_action is None else int(problem.dnn_action[i, j])
    if dnn is None or index < 0 or problem.uplink_latency is None:
        return None
    home = int(problem.home[i])
    on = network_on(dnn, float(problem.cycle[i]), kind_of(problem.nodes[home]),
                    kind_of(problem.nodes[j]))  # fmt: skip
    if isinstance(on, str):
        return None
    model = on.model
    if j == home:
        acts = actions(model, None, on.robot_factor, 1.0)
        local = acts[-1]
        why = "the plan keeps the network on its robot"
        if local.accuracy < model.min_accuracy:
            why = "no edge or cloud node meets the bounds, so the local model answers"
        return Choice(local, f"{local.name}: {why}", ())
    link = Link(
        latency=float(problem.uplink_latency[home] + problem.uplink_latency[j]),
        jitter=0.0,
        bandwidth=float(min(problem.uplink_bandwidth[home], problem.uplink_bandwidth[j])),
    )
    over = f"{link.bandwidth / 1e6:.3g} Mbit/s, {link.latency * 1e3:.3g} ms"
    return choose(model, actions(model, link, on.robot_factor, on.tail_factor), over)
