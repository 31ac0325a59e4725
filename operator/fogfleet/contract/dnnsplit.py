"""Where to cut a DNN between a robot and an off-board node: RoboEC2's Spotlight Criteria
Algorithm (roboec2-dnn-offloading, Section IV-C, eq. 8 and Algorithm 1), in the standard
library: the planner resolves a split module's split per candidate node with it
(``domain.dnnpairs``) and the robot's side of the workload per frame (DNNSPLIT.md 3.2).

A module whose network can be cut has three kinds of *action* (eq. 2): ``a = 0`` runs the whole
network off-board (the raw input crosses the link); ``a = 1..n`` runs the layers up to split
point ``a`` on the robot (the *head*) and the rest off-board (the *tail*; the split point's
tensor crosses); ``a = n+1`` runs the robot's local lightweight model (nothing crosses: the
answer when the link is gone). Each action has (eqs. 5-7):

* ``Time(a)``: robot computation + transfer of what crosses + off-board computation + the
  answer back, per frame. Transfer is bytes x 8 / bandwidth + the one-way latency
  (``Link``), each way; a cut link makes every off-board action's time
  infinite;
* ``Accu(a)``: the big model's accuracy for ``a <= n``, the local model's for ``n+1`` (eq. 6:
  "binary");
* ``Cost(a)``: the robot's computation per frame, in seconds (eq. 7 counts the layers computed
  locally; seconds on the robot are what fogfleet plans CPU with): 0 for full offload.

Times are declared on a reference core and scaled per node by a factor (time on the node =
reference time x factor: a Pi 4 core is ~25 times slower than the reference).

The rule (eq. 8: every action must meet ``Time <= alpha``, ``Accu >= theta``,
``Cost <= gamma``; Algorithm 1, lines 13-23, read as ``DNNSPLIT.md`` 3.1 explains):

1. drop every action slower than ``alpha`` or costing the robot more than ``gamma``;
2. drop the local model when its accuracy is below ``theta``, and when the spotlight is
   accuracy;
3. among what is left, the spotlight picks: **time** the fastest; **cost** the one that
   computes least on the robot (the most offloaded action that still meets ``alpha``);
   **accuracy** an off-board action (the big model), the least robot computation first;
4. when nothing is left (a cut link, a link too slow), the local model.

Ties go to the faster action, then to the lower action index.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

from .dnn import FULL_OFFLOAD

__all__ = [
    "FULL_OFFLOAD",
    "Action",
    "Choice",
    "DnnSplit",
    "SplitPoint",
    "Spotlight",
    "action_name",
    "actions",
    "choose",
]

BITS_PER_BYTE = 8


class Spotlight(StrEnum):
    """The metric a module cares most about (RoboEC2's "spotlight" parameter, eq. 8)."""

    TIME = "time"
    COST = "cost"
    ACCURACY = "accuracy"


class Link(Protocol):
    """A path between the robot and the off-board node, as the planner declares or measures it
    (``domain.network.Link``) or as the robot estimates it per frame."""

    @property
    def latency(self) -> float: ...  # seconds, one way

    @property
    def bandwidth(self) -> float: ...  # bit/s


@dataclass(frozen=True)
class SplitPoint:
    """One place the network can be cut: the head's and the tail's time on the reference core
    (seconds per frame) and the bytes of the tensor that crosses."""

    name: str
    head_s: float
    tail_s: float
    tensor_bytes: int


@dataclass(frozen=True)
class DnnSplit:
    """A module's network and the bounds it must meet (eq. 8: ``alpha``, ``theta``,
    ``gamma``): the whole network's off-board time, its split points in order from input to
    output, and the robot's local model."""

    spotlight: Spotlight
    max_latency_s: float  # alpha: a frame's answer within this
    min_accuracy: float  # theta
    max_robot_s: float | None  # gamma: the robot's computation per frame (None: no bound)
    input_bytes: int  # what crosses for full offload (Data^0)
    output_bytes: int  # the answer that comes back
    accuracy: float  # the big model's (every off-board action)
    full_s: float  # the whole network on the reference core
    split_points: tuple[SplitPoint, ...]
    local_name: str
    local_s: float  # the local model on the reference core
    local_accuracy: float


@dataclass(frozen=True)
class Action:
    """One action and its metrics (eqs. 5-7) for a given link and pair of nodes."""

    index: int  # 0 full offload, 1..n split point n, n+1 the local model
    name: str
    time_s: float  # Time(a); inf when the link is cut and the action crosses it
    robot_s: float  # Cost(a)
    accuracy: float  # Accu(a)
    crossing_bytes: int  # what crosses the link per frame (0: nothing)

    @property
    def offloaded(self) -> bool:
        """Something of it runs off the robot (a <= n)."""
        return self.crossing_bytes > 0


@dataclass(frozen=True)
class Choice:
    """The chosen action, why, and why each other action was not chosen."""

    action: Action
    reason: str
    dropped: tuple[tuple[Action, str], ...]


def action_name(model: DnnSplit, index: int) -> str:
    """Action ``index``'s name: ``FULL_OFFLOAD``, a split point's, or the local model's."""
    if index == 0:
        return FULL_OFFLOAD
    if index <= len(model.split_points):
        return model.split_points[index - 1].name
    return model.local_name


def _transfer_s(n_bytes: int, link: Link) -> float:
    """One way: serialisation at the link's bandwidth plus its latency."""
    return n_bytes * BITS_PER_BYTE / link.bandwidth + link.latency


def actions(
    model: DnnSplit, link: Link | None, robot_factor: float, tail_factor: float
) -> list[Action]:
    """Every action of ``model`` with its time, cost and accuracy when the tail runs on a node
    ``tail_factor`` times slower than the reference core, the head and the local model on a
    robot ``robot_factor`` times slower, over ``link`` (None: cut)."""

    def crossing(robot_s: float, n_bytes: int, tail_s: float) -> float:
        if link is None:
            return math.inf
        there = _transfer_s(n_bytes, link)
        back = _transfer_s(model.output_bytes, link)
        return robot_s + there + tail_s * tail_factor + back

    out = [
        Action(
            0,
            FULL_OFFLOAD,
            crossing(0.0, model.input_bytes, model.full_s),
            0.0,
            model.accuracy,
            model.input_bytes,
        )
    ]
    for k, point in enumerate(model.split_points, start=1):
        head = point.head_s * robot_factor
        time_s = crossing(head, point.tensor_bytes, point.tail_s)
        out.append(Action(k, point.name, time_s, head, model.accuracy, point.tensor_bytes))
    local = model.local_s * robot_factor
    out.append(
        Action(len(out), model.local_name, local, local, model.local_accuracy, crossing_bytes=0)
    )
    return out


def _why_dropped(model: DnnSplit, action: Action) -> str | None:
    """Why eq. 8's bounds or the spotlight drop ``action`` (None: it stays)."""
    if action.time_s > model.max_latency_s:
        took = "the link is cut" if math.isinf(action.time_s) else f"{_ms(action.time_s)}"
        return f"{took} > maxLatency {_ms(model.max_latency_s)}"
    if model.max_robot_s is not None and action.robot_s > model.max_robot_s:
        return f"robot {_ms(action.robot_s)} > maxRobot {_ms(model.max_robot_s)}"
    if not action.offloaded:
        if action.accuracy < model.min_accuracy:
            return f"accuracy {action.accuracy:g} < minAccuracy {model.min_accuracy:g}"
        if model.spotlight is Spotlight.ACCURACY:
            return "the spotlight is accuracy: an off-board action runs the big model"
    return None


def _key(spotlight: Spotlight, action: Action) -> tuple[float, ...]:
    """The spotlight's order (eq. 8's rewards): smaller first."""
    if spotlight is Spotlight.TIME:
        return (action.time_s, action.index)
    if spotlight is Spotlight.COST:
        return (action.robot_s, action.time_s, action.index)
    return (-action.accuracy, action.robot_s, action.time_s, action.index)


def choose(model: DnnSplit, candidates: Sequence[Action], over: str = "") -> Choice:
    """Algorithm 1 over ``candidates`` (``actions``): the module docstring's rule. ``over``
    names the link in the reason ("20 Mbit/s, 8 ms")."""
    dropped = [(a, why) for a in candidates if (why := _why_dropped(model, a)) is not None]
    gone = {a.index for a, _ in dropped}
    left = [a for a in candidates if a.index not in gone]
    local = candidates[-1]
    if not left:  # Algorithm 1: "it will take the action n+1"
        why = "nothing meets the bounds" + (f" over {over}" if over else "")
        if all(math.isinf(a.time_s) for a in candidates if a.offloaded):
            why = "the link is cut"
        rest = tuple(d for d in dropped if d[0].index != local.index)
        return Choice(local, f"{local.name}: {why}, so the local model answers", rest)
    best = min(left, key=lambda a: _key(model.spotlight, a))
    others = [
        (
            a,
            f"{model.spotlight.value}: {best.name} is better ({_measure(model, a)} against "
            f"{_measure(model, best)})",
        )
        for a in left
        if a != best
    ]
    reason = f"{best.name}: {_ms(best.time_s)} <= {_ms(model.max_latency_s)}"
    if best.offloaded:
        reason += f", {best.crossing_bytes} B crossing" + (f" over {over}" if over else "")
    reason += f" ({model.spotlight.value} spotlight)"
    local_out = next((why for a, why in dropped if a.index == local.index), None)
    if local_out is not None and best.index != local.index:
        reason += f"; the local model is out: {local_out}"
    return Choice(best, reason, (*dropped, *others))


def _measure(model: DnnSplit, action: Action) -> str:
    """What the spotlight compares of ``action``: its time, its robot time, or its accuracy
    with its robot time."""
    if model.spotlight is Spotlight.TIME:
        return _ms(action.time_s)
    if model.spotlight is Spotlight.COST:
        return f"robot {_ms(action.robot_s)}"
    return f"accuracy {action.accuracy:g}, robot {_ms(action.robot_s)}"


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.3g} ms"
