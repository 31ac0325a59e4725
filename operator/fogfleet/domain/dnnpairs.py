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

A network runs on one thread: under a CPU limit ``c`` below one core the kernel's quota lets
it run ``c`` of every period, so a frame takes ``time / c``; from one core on, ``time``. Its
profile rows (Fig. 3) are these, on the steps of ``CPU_STEPS``.
"""

from __future__ import annotations

import math

from fogfleet.api.v1alpha1.base import parse_quantity
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.dnn import Dnn
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.contract.dnnsplit import Action, Choice, DnnSplit, SplitPoint, actions, choose

from .network import Link
from .problem import EXEC_SHARE_OF_CYCLE, Problem
from .rows import ProfileRow

__all__ = [
    "CPU_STEPS",
    "dnn_rows",
    "local_pair_rows",
    "model_of",
    "off_board",
    "planned_choice",
    "resolve",
    "robot_row",
    "tail_rows",
]

CPU_STEPS = (0.1, 0.2, 0.25, 0.5, 0.75, 1.0)  # cores a network's pod may be given
BITS_PER_BYTE = 8


def model_of(dnn: Dnn, cycle_s: float) -> DnnSplit:
    """``SoftwareModule.spec.dnn`` in seconds (alpha defaults to the module's cycle)."""
    alpha = cycle_s if dnn.max_latency_millis is None else dnn.max_latency_millis / 1e3
    gamma = None if dnn.max_robot_millis is None else dnn.max_robot_millis / 1e3
    return DnnSplit(
        spotlight=dnn.spotlight,
        max_latency_s=alpha,
        min_accuracy=dnn.min_accuracy,
        max_robot_s=gamma,
        input_bytes=int(parse_quantity(dnn.input_bytes)),
        output_bytes=int(parse_quantity(dnn.output_bytes)),
        accuracy=dnn.accuracy,
        full_s=dnn.full_millis / 1e3,
        split_points=tuple(
            SplitPoint(
                p.name,
                p.head_millis / 1e3,
                p.tail_millis / 1e3,
                int(parse_quantity(p.tensor_bytes)),
            )
            for p in dnn.split_points
        ),
        local_name=dnn.local_model.name,
        local_s=dnn.local_model.robot_millis / 1e3,
        local_accuracy=dnn.local_model.accuracy,
    )


def dnn_rows(time_s: float, cap_cores: float) -> list[ProfileRow]:
    """A one-thread network of ``time_s`` per frame at one core, as rows at ``CPU_STEPS`` that
    fit a node of ``cap_cores`` (smallest CPU first)."""
    return [ProfileRow(c, time_s / min(c, 1.0), 0.0) for c in CPU_STEPS if c <= cap_cores + 1e-9]


def _factor(node: ComputeNode) -> float:
    """Time on ``node`` per second on the reference core (1 / speedFactor)."""
    return 1.0 / max(parse_quantity(node.spec.speed_factor), 1e-6)


def resolve(
    module: SoftwareModule,
    cycle_s: float,
    robot: ComputeNode | float,
    node: ComputeNode,
    link: Link,
) -> Choice:
    """The rule's choice for ``module``'s tail on ``node`` over ``link`` (``robot``: its robot, or
    the robot's time factor)."""
    assert module.spec.dnn is not None
    model = model_of(module.spec.dnn, cycle_s)
    rf = robot if isinstance(robot, float) else _factor(robot)
    return choose(model, actions(model, link, rf, _factor(node)))


def tail_rows(
    model: DnnSplit, action: Action, node: ComputeNode, cap_cores: float
) -> list[ProfileRow]:
    """The rows of the tail ``action`` leaves to ``node`` (the whole network for action 0)."""
    ref = model.full_s if action.index == 0 else model.split_points[action.index - 1].tail_s
    return dnn_rows(ref * _factor(node), cap_cores)


def off_board(
    module: SoftwareModule, cycle_s: float, robot_factor: float, node: ComputeNode, link: Link
) -> tuple[Choice, float, float, float] | str:
    """The tail on ``node``: (choice, time outside the tail, its jitter, bit/s crossing), or why
    the node is refused (no off-board action meets the bounds over this link)."""
    got = resolve(module, cycle_s, robot_factor, node, link)
    action = got.action
    if not action.offloaded:
        why = "; ".join(f"{a.name}: {w}" for a, w in got.dropped if a.offloaded)
        return f"no part of its network may run there over this link ({why})"
    assert module.spec.dnn is not None
    model = model_of(module.spec.dnn, cycle_s)
    tail = model.full_s if action.index == 0 else model.split_points[action.index - 1].tail_s
    outside = action.time_s - tail * _factor(node)
    crossing = (action.crossing_bytes + model.output_bytes) * BITS_PER_BYTE / cycle_s
    return got, outside, link.jitter * math.sqrt(2), crossing


def local_pair_rows(
    module: SoftwareModule, cycle_s: float, robot: ComputeNode, cap_cores: float, alone: bool
) -> list[ProfileRow] | str:
    """The local model's rows on its robot (action n+1), or why it may not answer alone there:
    below minAccuracy or over maxRobotMillis while an off-board node is left (``alone``: none)."""
    assert module.spec.dnn is not None
    model = model_of(module.spec.dnn, cycle_s)
    local_s = model.local_s * _factor(robot)
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
    module: SoftwareModule, cycle_s: float, robot: ComputeNode, cap_cores: float
) -> ProfileRow | None:
    """What the robot holds for the module wherever its tail runs: the head of the slowest
    split point or the local model, whichever takes longer (both stay on the robot; the local
    model answers the moment the link fails), at the smallest ``CPU_STEPS`` that keeps a frame
    within ``EXEC_SHARE_OF_CYCLE`` of alpha. It counts every split point's head, not only the
    planned one's: the robot applies the rule per frame from the link it measures (RoboEC2
    decides per frame), so a link that slows may move it to any split. None: no step fits."""
    assert module.spec.dnn is not None
    model = model_of(module.spec.dnn, cycle_s)
    slowest = max([model.local_s, *(p.head_s for p in model.split_points)])
    rows = dnn_rows(slowest * _factor(robot), cap_cores)
    if not rows:
        return None
    fit = [r for r in rows if r.mean <= EXEC_SHARE_OF_CYCLE * model.max_latency_s]
    return fit[0] if fit else rows[-1]


def planned_choice(problem: Problem, i: int, j: int) -> Choice | None:
    """The rule's choice for instance ``i`` with its tail on node ``j``, as the plan's build
    resolved it, its reason naming the link (None: ``i`` is not a split network's, or may not
    run on ``j``). On its own robot the local model answers alone."""
    inst = problem.instances[i]
    model = (problem.split_models or {}).get(inst.module)
    index = -1 if problem.dnn_action is None else int(problem.dnn_action[i, j])
    if model is None or index < 0 or problem.uplink_latency is None:
        return None
    home = int(problem.home[i])
    rf = 1.0 / max(problem.nodes[home].speed_factor, 1e-6)
    if j == home:
        acts = actions(model, None, rf, 1.0)
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
    tf = 1.0 / max(problem.nodes[j].speed_factor, 1e-6)
    over = f"{link.bandwidth / 1e6:.3g} Mbit/s, {link.latency * 1e3:.3g} ms"
    return choose(model, actions(model, link, rf, tf), over)
