"""The head's test bed: a clock the test moves, the robot's networks and a link with a tail
behind it, each taking its declared time on that clock (no ROS, no ONNX)."""

from __future__ import annotations

from collections.abc import Callable

from runspecs import SPEC

from fogfleet.workload.dnn.head import FrameResult, Head, Mailbox
from fogfleet.workload.dnn.runspec import DnnRunSpec
from fogfleet.workload.dnn.tail import Tail
from fogfleet.workload.dnn.wire import Kind, Packet

CYCLE = 0.1
ALPHA = 0.05
HEAD_S, LOCAL_S, TAIL_S, ONE_WAY = 0.002, 0.0004, 0.0012, 0.001
WHOLE_S = 0.008  # the whole network on the robot


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Parts:
    """The robot's networks: each takes its declared time on the test's clock."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock

    def capture(self, frame: int) -> int:
        return frame

    def head(self, index: int, frame: object) -> bytes:
        self.clock.t += HEAD_S
        return b"t" * (6272 if index == 2 else 401408 if index == 1 else 150528)

    def local(self, frame: object) -> bytes:
        self.clock.t += LOCAL_S
        return b"local"

    def whole(self, frame: object) -> bytes:
        self.clock.t += WHOLE_S
        return b"whole"


class TailParts:
    def tail(self, index: int, data: bytes) -> bytes:
        if index > 2:
            raise KeyError(index)
        return b"tail"


class Link:
    """The link and the tail node: what the head sends comes back one way later, plus the
    tail's time for a tensor; nothing while ``up`` is False."""

    def __init__(self, clock: Clock) -> None:
        self.clock, self.up = clock, True
        self.queue: list[tuple[float, Packet]] = []
        self.sent: list[Packet] = []
        self.tail = Tail(TailParts(), self._reply, clock)
        self.head: Head | None = None

    def send(self, packet: Packet) -> None:
        self.sent.append(packet)
        if self.up:
            self.tail.receive(packet)

    def _reply(self, packet: Packet) -> None:
        work = TAIL_S if packet.kind is Kind.ANSWER else 0.0
        self.queue.append((self.clock.t + 2 * ONE_WAY + work, packet))

    def deliver(self, until: float) -> None:
        assert self.head is not None
        self.queue.sort(key=lambda tp: tp[0])
        while self.queue and self.queue[0][0] <= until:
            at, packet = self.queue.pop(0)
            self.clock.t = max(self.clock.t, at)
            if packet.kind is Kind.ANSWER:
                packet = Packet(packet.kind, packet.action, packet.frame, packet.sent_ns,
                                round(TAIL_S * 1e6), packet.payload)  # fmt: skip
            self.head.receive(packet)


class FakeMailbox(Mailbox):
    """Replies are delivered up to ``until``; then the clock stands at ``until`` if the
    frame's answer did not come (the real mailbox would have waited that long)."""

    def __init__(self, clock: Clock, link: Link) -> None:
        super().__init__(clock)
        self.link, self.test_clock = link, clock

    def wait(self, frame: int, action: int, until: float) -> tuple[Packet, float] | None:
        self.link.deliver(until)
        if (frame, action) not in self._box:
            self.test_clock.t = max(self.test_clock.t, until)
        return super().wait(frame, action, until)


def setup_head(make: Callable[..., Head] = Head) -> tuple[Head, Link, Clock]:
    """A head (``make(run, parts, send, clock, mailbox)``) wired to a link with a tail."""
    clock = Clock()
    link = Link(clock)
    head = make(DnnRunSpec.from_raw(SPEC), Parts(clock), link.send, clock,
                FakeMailbox(clock, link))  # fmt: skip
    link.head = head
    return head, link, clock


def run_frames(head: Head, link: Link, clock: Clock, n: int) -> list[FrameResult]:
    out = []
    for _ in range(n):
        start = clock.t
        out.append(head.frame())
        link.deliver(start + CYCLE)
        clock.t = start + CYCLE
    return out
