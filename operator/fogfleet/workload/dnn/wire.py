"""The header before the bytes the head and the tail exchange (``contract.dnn``'s two topics).

Both topics carry ``std_msgs/UInt8MultiArray`` whose data is this fixed 32-byte header and then
the payload, so the tail needs no message type per split point: the action index says which
tail to run and the tail's own model says the tensor's shape and type.

=======  ======  =============================================================================
offset   type    field
=======  ======  =============================================================================
0        4s      magic ``FFDN`` (a foreign message is refused, not misread)
4        u8      version (``VERSION``)
5        u8      kind: ``TENSOR`` (head -> tail, a frame's tensor), ``ANSWER`` (tail -> head,
                 its answer), ``PROBE`` (head -> tail, no payload), ``ECHO`` (its reply)
6        u16     action index (contract.dnnsplit: 0 full offload, k the k-th split point)
8        u64     frame id (the head's count)
16       i64     send time, ns, on the *head's* clock: the tail copies it into its reply, so
                 the head measures the round trip on one clock (RoboEC2's "latency ...
                 measured in real time by a program on the robot", Section IV-B)
24       u32     the tail's compute time for this frame, µs (0 from the head)
28       u32     reserved (0)
=======  ======  =============================================================================

Network byte order. A probe travels before each frame's tensor: its echo is the link's round
trip with nothing to carry, so the head can tell the latency from the bandwidth
(``estimate.LinkEstimator``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

__all__ = ["HEADER_BYTES", "MAGIC", "VERSION", "Kind", "Packet", "decode", "encode"]

MAGIC = b"FFDN"
VERSION = 1
_HEADER = struct.Struct("!4sBBHQqII")
HEADER_BYTES = _HEADER.size
_U32 = 2**32 - 1


class Kind(IntEnum):
    TENSOR = 1
    ANSWER = 2
    PROBE = 3
    ECHO = 4


@dataclass(frozen=True)
class Packet:
    """One message: its header's fields and its payload."""

    kind: Kind
    action: int
    frame: int
    sent_ns: int
    tail_us: int = 0
    payload: bytes = b""


def encode(packet: Packet) -> bytes:
    """The header then the payload (ValueError for a field out of its range)."""
    if not 0 <= packet.action <= 0xFFFF:
        raise ValueError(f"action {packet.action}: 0 to 65535")
    if not 0 <= packet.frame < 2**64:
        raise ValueError(f"frame {packet.frame}: a 64-bit count")
    head = _HEADER.pack(
        MAGIC,
        VERSION,
        packet.kind,
        packet.action,
        packet.frame,
        packet.sent_ns,
        min(max(packet.tail_us, 0), _U32),
        0,
    )
    return head + packet.payload


def decode(data: bytes | bytearray | memoryview) -> Packet:
    """The packet in ``data`` (ValueError naming what is wrong: too short, not ours, a newer
    version, an unknown kind)."""
    view = memoryview(data)
    if len(view) < HEADER_BYTES:
        raise ValueError(f"{len(view)} bytes: shorter than the {HEADER_BYTES}-byte header")
    magic, version, kind, action, frame, sent, tail_us, _ = _HEADER.unpack_from(view)
    if magic != MAGIC:
        raise ValueError(f"magic {bytes(magic)!r}: not a fogfleet split-DNN message")
    if version != VERSION:
        raise ValueError(f"version {version}: this workload reads version {VERSION}")
    try:
        which = Kind(kind)
    except ValueError:
        raise ValueError(f"kind {kind}: one of {', '.join(str(int(k)) for k in Kind)}") from None
    return Packet(which, action, frame, sent, tail_us, bytes(view[HEADER_BYTES:]))
