"""The off-board side of a split module: answer whatever the head sends (no ROS here).

A probe is echoed at once (its round trip is the link's latency, ``estimate``). A tensor is
run through the tail its action names (the whole network for action 0, RoboEC2's full
offload; eq. 2), and the answer goes back with the head's send time and the tail's compute
time, which the head subtracts from the round trip. The tail keeps no state of its own: the
head decides; a restarted tail answers the next frame.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from .wire import Kind, Packet

__all__ = ["Tail", "TailParts"]


class TailParts(Protocol):
    """The tail node's networks (``sessions.TailNets``)."""

    def tail(self, index: int, data: bytes) -> bytes: ...


class Tail:
    def __init__(
        self,
        parts: TailParts,
        send: Callable[[Packet], None],
        clock: Callable[[], float],
        refused: Callable[[str], None] = lambda _: None,
    ) -> None:
        self.parts, self.send, self.clock, self.refused = parts, send, clock, refused
        self.answered = 0

    def receive(self, packet: Packet) -> None:
        if packet.kind is Kind.PROBE:
            self.send(Packet(Kind.ECHO, packet.action, packet.frame, packet.sent_ns))
            return
        if packet.kind is not Kind.TENSOR:
            return
        t0 = self.clock()
        try:
            answer = self.parts.tail(packet.action, packet.payload)
        except (KeyError, ValueError) as exc:  # an action or a tensor this tail does not have
            self.refused(f"frame {packet.frame}, action {packet.action}: {exc!r}")
            return
        tail_us = round((self.clock() - t0) * 1e6)
        self.send(Packet(Kind.ANSWER, packet.action, packet.frame, packet.sent_ns, tail_us, answer))
        self.answered += 1
