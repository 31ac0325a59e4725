"""Admission and routing of service requests across tiers (tinyKube section III-B).

Each request carries a privacy flag and a response-time target. Tiers are tried in preference
order (edge before cloud, as tinyKube's dispatcher "prioritizes available resources in the edge
cluster"): a private request only on tiers that accept private traffic, a normal one on any.
A tier admits the request when its response-time estimate -- tinyKube eq. 3 evaluated on the
queue the request would join, see :func:`estimate_response_seconds` -- meets the target. A
request no tier admits is rejected and counted.

On a tier that also serves private traffic, normal requests can be made to leave room for it
(trunk reservation): with ``reserve = r`` a normal request is judged as if ``r`` more requests
were queued ahead of it, so the last ``r`` places of the admissible queue are kept for private
requests, which have nowhere else to go. ``reserve = 0`` is tinyKube's dispatcher.

:func:`plan_dispatch` is the rate-level counterpart used for sizing: it splits arrival rates
over pools of given sizes with the M/M/k/K admission model of :mod:`.queueing`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from fogfleet.autoscaling import queueing

__all__ = [
    "DispatchPlan",
    "Tier",
    "TierLoad",
    "estimate_response_seconds",
    "plan_dispatch",
    "route",
]


@dataclass(frozen=True)
class Tier:
    """A pool's static properties as the dispatcher sees them."""

    name: str
    service_rate: float  # requests/s one replica completes (mu)
    network_delay_seconds: float = 0.0
    accepts_private: bool = False


@dataclass(frozen=True)
class TierLoad:
    """A pool's state at one instant: ready replicas and requests queued or in service."""

    ready_replicas: int
    in_system: int


def estimate_response_seconds(
    in_system: int, ready_replicas: int, service_rate: float, network_delay_seconds: float = 0.0
) -> float:
    """Expected response time of a request joining a FCFS pool now (tinyKube eq. 3, per state).

    With ``n`` requests present and ``k`` ready replicas, the newcomer waits for
    ``max(0, n - k + 1)`` departures at rate ``k mu`` and is then served at rate ``mu``.
    """
    if ready_replicas <= 0:
        return math.inf
    ahead = max(0, in_system - ready_replicas + 1)
    return network_delay_seconds + ahead / (ready_replicas * service_rate) + 1.0 / service_rate


def route(
    private: bool,
    target_seconds: float,
    tiers: Sequence[Tier],
    loads: Sequence[TierLoad],
    reserve: int = 0,
) -> int | None:
    """Index of the tier that admits the request, or ``None`` if it is rejected.

    Private requests are never routed to a tier that does not accept private traffic.
    """
    for index, (tier, load) in enumerate(zip(tiers, loads, strict=True)):
        if private and not tier.accepts_private:
            continue
        ahead = load.in_system + (reserve if tier.accepts_private and not private else 0)
        estimate = estimate_response_seconds(
            ahead, load.ready_replicas, tier.service_rate, tier.network_delay_seconds
        )
        if estimate <= target_seconds:
            return index
    return None


@dataclass(frozen=True)
class DispatchPlan:
    """Expected arrival rate admitted per tier and the rates rejected, per class."""

    tier_rates: tuple[float, ...]
    private_rejected: float
    normal_rejected: float


def plan_dispatch(
    private_rate: float,
    normal_rate: float,
    tiers: Sequence[Tier],
    replicas: Sequence[int],
    target_seconds: Sequence[float],
    reserve: int = 0,
) -> DispatchPlan:
    """Split arrival rates over pools of the given sizes, tier by tier in preference order.

    Each tier refuses a share of what is offered to it -- the M/M/k/K blocking probability of
    :func:`queueing.admission_reject_probability`, or with a ``reserve`` on a private tier
    :func:`queueing.reservation_blocking` -- and what it refuses of the normal traffic overflows
    to the next tier (as a Poisson stream: an approximation). Private traffic refused by the
    last private tier is rejected.
    """
    rates: list[float] = []
    private_left, normal_left = private_rate, normal_rate
    for tier, k, target in zip(tiers, replicas, target_seconds, strict=True):
        offered_private = private_left if tier.accepts_private else 0.0
        mu, delay = tier.service_rate, tier.network_delay_seconds
        if k <= 0:
            rates.append(0.0)  # nothing admitted; everything moves on to the next tier
            continue
        if reserve and tier.accepts_private:
            capacity = queueing.admission_capacity(k, mu, target, delay=delay)
            block_p, block_n = queueing.reservation_blocking(
                offered_private, normal_left, mu, k, capacity, capacity - reserve
            )
        else:
            block_p = block_n = queueing.admission_reject_probability(
                offered_private + normal_left, mu, k, target, delay=delay
            )
        admitted = offered_private * (1 - block_p) + normal_left * (1 - block_n)
        rates.append(admitted)
        if tier.accepts_private:
            private_left = offered_private * block_p
        normal_left *= block_n
    return DispatchPlan(tuple(rates), private_left, normal_left)
