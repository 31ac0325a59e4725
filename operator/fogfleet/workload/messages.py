"""The header every workload message carries: who sent it, when, and which input it answers.

Carried in a ``std_msgs/String`` as ``robot|module|seq|sent_ns|origin_ns|`` padded to the
topic's ``sizeBytes``: receivers measure transfer latency and count messages from other robots
(leakage) without knowing the sender's type.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Header", "decode", "encode"]


@dataclass(frozen=True)
class Header:
    robot: str
    module: str
    seq: int
    sent_ns: int
    origin_ns: int  # when the input this output answers was sent (0: none)


def encode(header: Header, size_bytes: int) -> str:
    text = f"{header.robot}|{header.module}|{header.seq}|{header.sent_ns}|{header.origin_ns}|"
    return text + "." * max(0, size_bytes - len(text))


def decode(data: str) -> Header | None:
    parts = data.split("|", 5)
    if len(parts) < 6:
        return None
    try:
        return Header(parts[0], parts[1], int(parts[2]), int(parts[3]), int(parts[4]))
    except ValueError:
        return None
