"""A free loopback port for the workload processes these tests start (DDS and metrics), and
reading their metrics."""

from __future__ import annotations

import re
import socket
import urllib.request


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def fogfleet_metrics(port: int) -> dict[str, float]:
    """The fogfleet_* samples a workload on ``port`` serves, by name and labels (summed)."""
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out: dict[str, float] = {}
    for line in text.splitlines():
        m = re.match(r"^(fogfleet_\w+)(\{[^}]*\})?\s+([0-9.eE+-]+)$", line)
        if m:
            key = m.group(1) + (m.group(2) or "")
            out[key] = out.get(key, 0.0) + float(m.group(3))
    return out
