"""What the head learns per frame: the link (latency, bandwidth) and the real time of each part.

RoboEC2 estimates a frame's transfer time online from what the robot measures ("estimation is
suffice", Section IV-B, eq. 5); DNNSPLIT.md 3.5 starts with an EWMA of round trips and bytes
per second. Two measurements per frame, both on the head's own clock:

* a **probe** (a header with no payload, ``wire.Kind.PROBE``) and its echo: the round trip
  with nothing to carry, ``2 x latency``;
* the frame's **answer**: its round trip minus the tail's reported compute time is both
  transfers, ``2 x latency + bytes x 8 / bandwidth``; the part over the probe's round trip is
  the bytes' serialisation, which gives bytes per second.

The bandwidth is the ratio of two EWMAs (bytes moved, seconds spent moving them), so a frame
that moves more bytes weighs more, and one transfer too quick to time (on a host's loopback)
makes it large, not infinite or negative. Nothing known yet (no echo): ``link()`` is None and
the head keeps the plan's action (``head.Head``).

``PartTimes`` keeps an EWMA of each part's real time (the head of a split, the local model on
the robot; the tail of a split or the whole network on the tail node, as the tail reports
it) and turns it into the rule's terms: the reference time the rule scales by the node's
factor (``contract.dnnsplit.actions``). A part never run yet keeps its declared time, scaled by
what the measured parts on its side say the factor really is.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from fogfleet.contract.dnnsplit import Action, DnnSplit

__all__ = ["EWMA_WEIGHT", "Ewma", "LinkEstimate", "LinkEstimator", "PartTimes"]

# The weight of the newest sample: 0.2 is a memory of about five frames (1 / 0.2), half a
# second at 10 Hz, short enough to follow a link that changes between plans (DNNSPLIT.md 3.4
# steps a robot's link) and long enough that one late frame does not swing the choice.
EWMA_WEIGHT = 0.2
MIN_TRANSFER_S = 1e-6  # a transfer shorter than this is timed as this (no division by zero)


@dataclass
class Ewma:
    """An exponentially weighted moving average; the first sample is taken as it is."""

    weight: float = EWMA_WEIGHT
    value: float | None = None

    def add(self, sample: float) -> float:
        self.value = (
            sample if self.value is None else self.value + self.weight * (sample - self.value)
        )
        return self.value


@dataclass(frozen=True)
class LinkEstimate:
    """``contract.dnnsplit.Link``: one way latency (s), bandwidth (bit/s)."""

    latency: float
    bandwidth: float


@dataclass
class LinkEstimator:
    """The link as the last few probes and answers measured it."""

    round_trip: Ewma = field(default_factory=Ewma)  # a probe's: 2 x latency
    moved_bytes: Ewma = field(default_factory=Ewma)
    moving_s: Ewma = field(default_factory=Ewma)

    def echo(self, round_trip_s: float) -> None:
        """A probe's echo came back after ``round_trip_s``."""
        self.round_trip.add(max(0.0, round_trip_s))

    def answer(self, round_trip_s: float, tail_s: float, moved_bytes: int) -> None:
        """A frame's answer came back ``round_trip_s`` after its tensor left; the tail computed
        for ``tail_s``; ``moved_bytes`` crossed (the tensor and the answer)."""
        both_ways = max(0.0, round_trip_s - tail_s)
        base = self.round_trip.value if self.round_trip.value is not None else 0.0
        self.moved_bytes.add(float(moved_bytes))
        self.moving_s.add(max(MIN_TRANSFER_S, both_ways - base))

    def too_slow(self, waited_s: float, moved_bytes: int) -> None:
        """``moved_bytes`` did not come back in ``waited_s`` although the link answers probes:
        the bandwidth is below ``moved_bytes x 8 / waited_s``. A bound, not a sample (its
        answer may never come): the estimate is capped there, never raised."""
        waited = max(MIN_TRANSFER_S, waited_s)
        if self.moved_bytes.value is None or self.moving_s.value is None:
            self.moved_bytes.value, self.moving_s.value = float(moved_bytes), waited
            return
        at_cap = self.moved_bytes.value * waited / max(moved_bytes, 1)
        self.moving_s.value = max(self.moving_s.value, at_cap)

    @property
    def echoed(self) -> bool:
        """A probe came back: the link is up, if not yet measured."""
        return self.round_trip.value is not None

    def link(self) -> LinkEstimate | None:
        """The estimate, or None until a probe and a frame's answer have come back (the
        bandwidth is unknown before: ``decide.Decider`` then holds the plan's action)."""
        if self.round_trip.value is None:
            return None
        if self.moved_bytes.value is None or self.moving_s.value is None:
            return None
        bandwidth = self.moved_bytes.value * 8 / self.moving_s.value
        return LinkEstimate(self.round_trip.value / 2, bandwidth)


@dataclass
class PartTimes:
    """Measured seconds per part on its own node: ``head`` by split index (1..n), ``tail``
    by action index (0: the whole network), ``local`` the local model."""

    model: DnnSplit
    robot_factor: float
    tail_factor: float
    head: dict[int, Ewma] = field(default_factory=dict)
    tail: dict[int, Ewma] = field(default_factory=dict)
    local: Ewma = field(default_factory=Ewma)
    # the robot's CPU for a part (its thread's CPU time), by action index: what maxRobotMillis
    # bounds. The wall times above also hold the waits for a CPU (a throttled pod, a busy core),
    # which belong in the frame's time but are not computation
    robot_cpu: dict[int, Ewma] = field(default_factory=dict)

    def ran_head(self, index: int, seconds: float, cpu_s: float | None = None) -> None:
        self.head.setdefault(index, Ewma()).add(seconds)
        self.robot_cpu.setdefault(index, Ewma()).add(seconds if cpu_s is None else cpu_s)

    def ran_tail(self, index: int, seconds: float) -> None:
        self.tail.setdefault(index, Ewma()).add(seconds)

    def ran_local(self, seconds: float, cpu_s: float | None = None) -> None:
        self.local.add(seconds)
        index = len(self.model.split_points) + 1
        self.robot_cpu.setdefault(index, Ewma()).add(seconds if cpu_s is None else cpu_s)

    def with_robot_cpu(self, cands: list[Action]) -> list[Action]:
        """``cands`` with each measured part's robot cost its CPU time, not its wall time."""
        out = []
        for a in cands:
            cpu = self.robot_cpu.get(a.index)
            out.append(a if cpu is None or cpu.value is None else replace(a, robot_s=cpu.value))
        return out

    def _declared_head(self, index: int) -> float:
        return self.model.split_points[index - 1].head_s

    def _declared_tail(self, index: int) -> float:
        return self.model.full_s if index == 0 else self.model.split_points[index - 1].tail_s

    def factors(self) -> tuple[float, float]:
        """(robot, tail) factors: the mean ratio of measured to declared time of the parts
        measured on each side, the plan's where nothing was measured yet."""
        robot = [(e.value, self._declared_head(k)) for k, e in self.head.items()]
        if self.local.value is not None:
            robot.append((self.local.value, self.model.local_s))
        tail = [(e.value, self._declared_tail(k)) for k, e in self.tail.items()]
        return _ratio(robot, self.robot_factor), _ratio(tail, self.tail_factor)

    def model_now(self) -> tuple[DnnSplit, float, float]:
        """The rule's model with every measured part's reference time replaced by its
        measured time over the factor, and the two factors: ``actions(model, link, robot,
        tail)`` then predicts each measured part at its measured time."""
        robot, tail = self.factors()
        points = []
        for k, p in enumerate(self.model.split_points, start=1):
            h, t = self.head.get(k), self.tail.get(k)
            points.append(
                replace(
                    p,
                    head_s=p.head_s if h is None or h.value is None else h.value / robot,
                    tail_s=p.tail_s if t is None or t.value is None else t.value / tail,
                )
            )
        whole = self.tail.get(0)
        model = replace(
            self.model,
            split_points=tuple(points),
            full_s=self.model.full_s
            if whole is None or whole.value is None
            else whole.value / tail,
            local_s=self.model.local_s if self.local.value is None else self.local.value / robot,
        )
        return model, robot, tail


def _ratio(pairs: list[tuple[float | None, float]], default: float) -> float:
    ratios = [m / d for m, d in pairs if m is not None and d > 0]
    return sum(ratios) / len(ratios) if ratios else default
