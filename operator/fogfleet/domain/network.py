"""Link model: a robot reaches a node over its own uplink plus the node's uplink.

The paper measures message transfer times per link type (Wi-Fi, LAN, Ethernet to cloud;
III-E "Prior Data"). We model a path as the sum of the two uplinks' latencies, the root-sum-
square of their jitters and the smaller bandwidth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fogfleet.api.v1alpha1.base import parse_mbps, parse_millis, parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNodeSpec, LinkType

__all__ = ["LOCAL", "Link", "path", "uplink"]


@dataclass(frozen=True)
class Link:
    latency: float  # seconds
    jitter: float  # seconds (standard deviation)
    bandwidth: float  # bit/s
    loss: float = 0.0  # fraction


LOCAL = Link(latency=50e-6, jitter=10e-6, bandwidth=10e9)

# Used when a node declares no link: typical figures (Wi-Fi 6 robot uplink, 1 GbE edge LAN,
# WAN to a cloud region). They are only defaults; the examples declare their links.
DEFAULT_UPLINK = {
    Tier.ROBOT: Link(latency=3e-3, jitter=2e-3, bandwidth=200e6),
    Tier.EDGE: Link(latency=0.2e-3, jitter=0.05e-3, bandwidth=1e9),
    Tier.CLOUD: Link(latency=20e-3, jitter=5e-3, bandwidth=500e6),
}


def uplink(spec: ComputeNodeSpec) -> Link:
    """The node's uplink: the first declared non-loopback link, else the tier's default."""
    for link in spec.network:
        if link.type is LinkType.LOOPBACK:
            continue
        return Link(
            latency=parse_millis(link.latency_millis),
            jitter=parse_millis(link.jitter_millis),
            bandwidth=max(parse_mbps(link.bandwidth_mbps), 1.0),
            loss=parse_quantity(link.loss_percent) / 100.0,
        )
    return DEFAULT_UPLINK[spec.tier]


def path(a: Link, b: Link) -> Link:
    """Two uplinks in series."""
    return Link(
        latency=a.latency + b.latency,
        jitter=math.hypot(a.jitter, b.jitter),
        bandwidth=min(a.bandwidth, b.bandwidth),
        loss=1.0 - (1.0 - a.loss) * (1.0 - b.loss),
    )
