"""The robot's side of a split module, one frame at a time (no ROS, no onnxruntime here).

Per frame (one every ``cycleTimeMillis``): decide (``decide.Decider``), send a probe, run the
head of the chosen split (or nothing, for full offload) and send what crosses, then wait for
the tail's answer until ``alpha`` after the frame began. No answer by then: the link is taken
as cut and the resident local model answers (RoboEC2: "to deal with extreme conditions such as
disconnection, RoboEC2 deploys two models", Section IV-A), so the frame is still answered
within alpha + the local model's time; it is counted (``FrameResult.by``). When the local model
is the action, it answers at once and the probe alone watches the link come back.

The clock, the networks, the sender and the mailbox of replies are injected: the unit tests
drive a frame with a clock they move; ``ros.py`` wires rclpy, onnxruntime and the metrics.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Protocol

from .decide import Decider
from .runspec import DnnRunSpec
from .wire import Kind, Packet

__all__ = [
    "EXPLORE_FRAMES",
    "LOST_AFTER_FRAMES",
    "MAX_IN_FLIGHT",
    "By",
    "FrameResult",
    "Head",
    "Mailbox",
    "RobotParts",
]

MAX_IN_FLIGHT = 50  # frames whose late answer still measures the link (5 s at 10 Hz)
# Every this many frames, over a link that is up, the smallest split's tensor is also sent as a
# trial unless that split is the action (the frame is answered by its own action): the trial's
# head and tail times and its answer's round trip re-measure a split the rule no longer picks,
# which nothing else would. Without it one slow first frame (a tail still starting, a throttled
# head) or a slow spell keeps that split's estimate, and the head off it, for good (1 s at 10 Hz)
EXPLORE_FRAMES = 10
# A timed-out frame's answer still missing when the probe of the frame this many later echoes in
# time is taken as lost (its bytes bound the bandwidth, ``Head._still_up``); one that arrives
# before is a late sample like any other (a frame just over alpha on a jittery link, not a link
# too slow for what crossed: one such frame once capped the estimate and left no split in alpha)
LOST_AFTER_FRAMES = 2


class By(StrEnum):
    """Who answered a frame."""

    TAIL = "tail"  # the off-board action's answer came within alpha
    LOCAL = "local"  # the local model was the action
    TIMEOUT = "local after timeout"  # the tail's answer did not come within alpha
    ROBOT = "robot"  # the whole network on the robot (``whole.WholeHead``)
    UNANSWERED = "unanswered"  # no answer, and no local model to give one (``whole``)


class RobotParts(Protocol):
    """The robot's networks (``sessions.RobotNets``)."""

    def capture(self, frame: int) -> Any: ...

    def head(self, index: int, frame: Any) -> bytes: ...

    def local(self, frame: Any) -> bytes: ...


@dataclass(frozen=True)
class FrameResult:
    frame: int
    action: str  # the action run (a timed-out frame: the off-board one it tried)
    by: By
    answer: bytes
    started: float  # the clock's seconds
    predicted_s: float
    real_s: float
    proposed: str  # the rule's proposal this frame ("" before the link is known)
    reason: str

    @property
    def late(self) -> bool:
        """Longer than alpha (set by ``Head``)."""
        return self.real_s > self.alpha_s

    alpha_s: float = float("inf")
    robot_s: float = 0.0  # the robot's CPU for this frame (heads, the local model)


class Mailbox:
    """The tail's answers by (frame, action), handed from the receiving thread to the frame's
    (a frame may have two tensors in flight: its action's and a trial's)."""

    def __init__(self, clock: Callable[[], float]) -> None:
        self.clock = clock
        self._cond = threading.Condition()
        self._box: dict[tuple[int, int], tuple[Packet, float]] = {}

    def put(self, packet: Packet, at: float) -> None:
        with self._cond:
            self._box[packet.frame, packet.action] = (packet, at)
            self._cond.notify_all()

    def wait(self, frame: int, action: int, until: float) -> tuple[Packet, float] | None:
        """Frame ``frame``'s answer for ``action`` and its arrival, or None when ``until``
        passes first; every older answer is forgotten (a late answer is of no use: its frame
        was answered)."""
        with self._cond:
            while True:
                got = self._box.pop((frame, action), None)
                if got is not None or self.clock() >= until:
                    for old in [k for k in self._box if k[0] < frame]:
                        del self._box[old]
                    return got
                self._cond.wait(until - self.clock())


class Head:
    """One split module's robot side: ``frame()`` per cycle, ``receive()`` per reply."""

    def __init__(
        self,
        run: DnnRunSpec,
        parts: RobotParts,
        send: Callable[[Packet], None],
        clock: Callable[[], float],
        mailbox: Mailbox | None = None,
        cpu_clock: Callable[[], float] | None = None,
    ) -> None:
        self.run, self.parts, self.send, self.clock = run, parts, send, clock
        # the frame thread's CPU time (the robot's computation; the wall clock if not given)
        self.cpu_clock = clock if cpu_clock is None else cpu_clock
        self.decider = Decider(run)
        self.mailbox = mailbox if mailbox is not None else Mailbox(clock)
        self.lock = threading.Lock()  # the decider: the frame's thread and the receiver's
        self.count = 0
        self.probes: dict[int, float] = {}  # frame -> when its probe left (until echoed)
        self.echoed_in_time: dict[int, bool] = {}
        self.tensors: dict[tuple[int, int], int] = {}  # (frame, action) -> bytes sent
        # a frame whose answer missed alpha while its probe came back: (frame, bytes, waited)
        self.slow_evidence: tuple[int, int, float] | None = None

    def receive(self, packet: Packet) -> None:
        """A reply from the tail (an echo or an answer), as it arrives. Every reply measures
        the link, a late one too (a slow link is not a cut: its answers say how slow)."""
        now = self.clock()
        if packet.kind is Kind.ECHO:
            with self.lock:
                sent = self.probes.pop(packet.frame, None)
                if sent is None:
                    return
                rtt = now - packet.sent_ns / 1e9
                self.decider.link.echo(rtt)
                self.echoed_in_time[packet.frame] = rtt <= self.decider.alpha
                if rtt <= self.decider.alpha:
                    self._still_up(packet.frame)
        elif packet.kind is Kind.ANSWER:
            with self.lock:
                sent_bytes = self.tensors.pop((packet.frame, packet.action), None)
                if sent_bytes is not None:
                    tail_s = packet.tail_us / 1e6
                    rtt = now - packet.sent_ns / 1e9
                    self.decider.link.answer(rtt, tail_s, sent_bytes + len(packet.payload))
                    self.decider.parts.ran_tail(packet.action, tail_s)
                    if self.slow_evidence is not None and self.slow_evidence[0] == packet.frame:
                        self.slow_evidence = None  # late, not lost: its round trip is measured
            self.mailbox.put(packet, now)

    def trial_index(self) -> int | None:
        """The split whose tensor is the fewest bytes: the one a trial sends (None: none)."""
        points = self.run.model.split_points
        if not points:
            return None
        return min(range(len(points)), key=lambda i: points[i].tensor_bytes) + 1

    def _track(self, n: int, action: int, sent_bytes: int) -> None:
        """A tensor in flight, until its answer measures the link (the lock is held)."""
        self.tensors = {k: b for k, b in self.tensors.items() if k[0] > n - MAX_IN_FLIGHT}
        self.tensors[n, action] = sent_bytes

    def _send_tensor(self, n: int, k: int, image: Any) -> tuple[int, float, float]:
        """Run action ``k``'s head on frame ``n``'s image (the raw frame for full offload),
        count its time and send what crosses; (bytes sent, when they left, the robot's CPU
        seconds)."""
        t0, c0 = self.clock(), self.cpu_clock()
        data = self.parts.head(k, image)
        t1, cpu = self.clock(), self.cpu_clock() - c0
        with self.lock:
            if k > 0:
                self.decider.parts.ran_head(k, t1 - t0, cpu)
            self._track(n, k, len(data))
        self.send(Packet(Kind.TENSOR, k, n, int(t1 * 1e9), payload=data))
        return len(data), t1, cpu

    def _trial(self, n: int, image: Any, k: int) -> float:
        """Send frame ``n``'s tensor at split ``k`` without waiting for its answer, when the
        link is up; its head time counts, its answer measures the link and the tail
        (``receive``). Returns the robot's seconds spent on it."""
        with self.lock:
            if self.decider.cut:
                return 0.0
        return self._send_tensor(n, k, image)[2]

    def _still_up(self, frame: int) -> None:
        """A later frame's probe came back in time after ``slow_evidence``'s frame timed out
        and its answer did not (``LOST_AFTER_FRAMES``): the link stayed up, so it was too slow
        for what crossed. That answer may never come (a slow link's queue drops a large
        tensor), so the time waited bounds the bandwidth
        (``LinkEstimator.too_slow``): without it a head whose action no answer comes back for
        keeps the fast link's estimate and tries that action again after every cut (RoboEC2
        learns the transfer time from what the robot measures, Section IV-B). A probe lost
        instead (the link or the tail gone) drops the evidence: a cut says nothing of speed."""
        if self.slow_evidence is not None and frame >= self.slow_evidence[0] + LOST_AFTER_FRAMES:
            _, sent_bytes, waited = self.slow_evidence
            self.decider.link.too_slow(waited, sent_bytes + self.run.model.output_bytes)
            self.slow_evidence = None

    def _link_state(self) -> None:
        """The previous frames' probes: one echoed within alpha clears a cut; one whose alpha
        passed without an echo makes one (RoboEC2: a link is disconnected or not, per step)."""
        now, alpha = self.clock(), self.decider.alpha
        for f, sent in list(self.probes.items()):
            if now - sent > alpha:
                del self.probes[f]
                self.echoed_in_time[f] = False
                self.slow_evidence = None  # a cut: nothing learnt of the link's speed
        for f in sorted(self.echoed_in_time):
            self.decider.cut = not self.echoed_in_time.pop(f)

    def frame(self) -> FrameResult:
        """Run one frame; its answer, who gave it and how long it took."""
        start = self.clock()
        self.count += 1
        n = self.count
        with self.lock:
            self._link_state()
            decision = self.decider.decide()
            self.probes[n] = start
        action = decision.action
        stamp = int(start * 1e9)
        self.send(Packet(Kind.PROBE, action.index, n, stamp))
        image = self.parts.capture(n)
        by, answer, robot_s = By.LOCAL, b"", 0.0
        if action.offloaded:
            sent_bytes, t1, cpu = self._send_tensor(n, action.index, image)
            robot_s += cpu
            got = self.mailbox.wait(n, action.index, start + self.decider.alpha)
            if got is not None:
                by, answer = By.TAIL, got[0].payload
            else:
                with self.lock:
                    self.decider.cut = True
                    # its probe's echo tells of the link before the tensor, not after: it
                    # must not clear this cut; a later probe's will (``_still_up``)
                    if self.echoed_in_time.pop(n, False):  # up when it left: slow, or gone?
                        self.slow_evidence = (n, sent_bytes, self.clock() - t1)
                by = By.TIMEOUT
        if by is not By.TAIL:
            t0, c0 = self.clock(), self.cpu_clock()
            answer = self.parts.local(image)
            wall, cpu = self.clock() - t0, self.cpu_clock() - c0
            robot_s += cpu
            with self.lock:
                self.decider.parts.ran_local(wall, cpu)
        end = self.clock()
        k = self.trial_index()
        if n % EXPLORE_FRAMES == 0 and k is not None and k != action.index:
            robot_s += self._trial(n, image, k)  # after the frame's answer: it waits for none
        proposed = decision.proposed
        return FrameResult(
            frame=n,
            action=action.name,
            by=by,
            answer=answer,
            started=start,
            predicted_s=decision.predicted_s,
            real_s=end - start,
            proposed="" if proposed is None else proposed.action.name,
            reason="" if proposed is None else proposed.reason,
            alpha_s=self.decider.alpha,
            robot_s=robot_s,
        )
