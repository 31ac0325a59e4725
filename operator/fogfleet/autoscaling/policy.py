"""Scaling policies: a :class:`MetricsSnapshot` in, a :class:`ScaleDecision` out.

A policy recommends replicas per pool (tier) from the metrics of :mod:`.contract`;
:func:`decide` then applies the guard rails every policy shares, in this order:

1. **Missing metrics** (Prometheus unreachable, no samples): hold the last decision (or the
   current replicas), flag ``metrics_missing`` and leave the behaviour memory untouched -- the
   HPA likewise skips a target whose metrics it cannot read (ARCHITECTURE.md, "Scaling").
2. **Bounds**: never below ``min_replicas`` (and never below 1 for a safety-relevant service,
   whatever the spec says), never above ``max_replicas``.
3. **Behaviour**: stabilisation windows and rate limits of :mod:`.behavior`, per pool.

Policies:

* :class:`ReactiveCpu` -- the HPA's resource-metric formula ``ceil(ready * u / target)`` with
  the 10 % tolerance and the not-ready-pod rules of ``replica_calculator.go``; at an 80 % target
  with the tinyKube behaviour it is tinyKube's auto-scaler (section IV-C), the baseline.
* :class:`ReactiveSlo` -- the same formula on the measured SLO value (e.g. p95 latency) over its
  target.
* :class:`Predictive` -- sizes every pool from the arrival rates with the queueing model
  (section III-B): forecast the demand one setup time plus one period ahead, split it over the
  tiers as the dispatcher will (:func:`.dispatch.plan_dispatch`), and pick the fewest replicas
  for which admission refuses at most ``1 - percentile`` of each class.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

from fogfleet.autoscaling import queueing
from fogfleet.autoscaling.behavior import Behavior, BehaviorState, normalize
from fogfleet.autoscaling.dispatch import Tier, plan_dispatch

__all__ = [
    "MetricsSnapshot",
    "Policy",
    "Pool",
    "Predictive",
    "ReactiveCpu",
    "ReactiveSlo",
    "ScaleDecision",
    "ScalerState",
    "TierMetrics",
    "decide",
    "hpa_replicas",
    "size_pools",
]


@dataclass(frozen=True)
class Pool:
    """Static configuration of one tier's replica pool (from ``ScalingSpec.pools``)."""

    name: str
    min_replicas: int
    max_replicas: int
    service_rate: float  # requests/s per replica (mu), from profiling or the histogram
    target_seconds: float  # SLO target of this tier
    percentile: float = 0.95  # SLO percentile as a fraction
    setup_seconds: float = 0.0
    network_delay_seconds: float = 0.0
    accepts_private: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.min_replicas <= self.max_replicas:
            raise ValueError(f"pool {self.name}: need 0 <= min_replicas <= max_replicas")

    @property
    def tier(self) -> Tier:
        return Tier(self.name, self.service_rate, self.network_delay_seconds, self.accepts_private)


@dataclass(frozen=True)
class TierMetrics:
    """What Prometheus says about one pool. ``None`` means the metric is unavailable."""

    name: str
    replicas: int  # the pool's current desired count (Deployment spec.replicas)
    ready_replicas: int
    cpu_utilization: float | None = None  # mean over ready pods, as a fraction of the request
    slo_value_seconds: float | None = None  # measured SLO metric, e.g. p95 response time


@dataclass(frozen=True)
class MetricsSnapshot:
    """One read of the metrics contract at ``timestamp`` (seconds)."""

    timestamp: float
    tiers: tuple[TierMetrics, ...]
    private_rate: float | None = None  # requests/s offered (served + rejected), private
    normal_rate: float | None = None  # requests/s offered, normal

    def tier(self, name: str) -> TierMetrics:
        for tier in self.tiers:
            if tier.name == name:
                return tier
        raise KeyError(name)


@dataclass(frozen=True)
class ScaleDecision:
    timestamp: float
    replicas: Mapping[str, int] = field(hash=False)
    reason: str
    metrics_missing: bool = False


@dataclass(frozen=True)
class ScalerState:
    """The scaler's memory between decisions, per pool; start with ``ScalerState()``."""

    behavior: Mapping[str, BehaviorState] = field(default_factory=dict, hash=False)
    last: ScaleDecision | None = None
    previous: MetricsSnapshot | None = None


class Policy(Protocol):
    @property
    def name(self) -> str: ...

    def recommend(
        self, snapshot: MetricsSnapshot, pools: Sequence[Pool], previous: MetricsSnapshot | None
    ) -> tuple[dict[str, int], str] | None:
        """Replicas per pool and a reason, or ``None`` when the needed metrics are missing."""
        ...


def hpa_replicas(replicas: int, ready: int, usage_ratio: float, tolerance: float = 0.1) -> int:
    """The HPA's replica count for a resource metric (``GetResourceReplicas``).

    ``usage_ratio`` is the mean utilisation of the ready pods over the target. Pods that are
    not ready are ignored, except when scaling up, where they count as using nothing (so a
    scale-up already under way is not repeated). Within the tolerance nothing changes.
    """
    unready = max(0, replicas - ready)
    if ready <= 0:
        return replicas
    if unready == 0 or usage_ratio <= 1.0:
        if abs(1.0 - usage_ratio) <= tolerance:
            return replicas
        return math.ceil(usage_ratio * ready)
    new_ratio = usage_ratio * ready / (ready + unready)
    if abs(1.0 - new_ratio) <= tolerance or new_ratio < 1.0:
        return replicas
    return max(replicas, math.ceil(new_ratio * (ready + unready)))


@dataclass(frozen=True)
class ReactiveCpu:
    """HPA on CPU utilisation; tinyKube's baseline at ``target = 0.8``."""

    target: float = 0.8
    tolerance: float = 0.1
    name: str = "reactive-cpu"

    def recommend(
        self, snapshot: MetricsSnapshot, pools: Sequence[Pool], previous: MetricsSnapshot | None
    ) -> tuple[dict[str, int], str] | None:
        out: dict[str, int] = {}
        for pool in pools:
            m = snapshot.tier(pool.name)
            if m.cpu_utilization is None:
                return None
            out[pool.name] = hpa_replicas(
                m.replicas, m.ready_replicas, m.cpu_utilization / self.target, self.tolerance
            )
        return out, f"CPU utilisation against a {self.target:.0%} target"


@dataclass(frozen=True)
class ReactiveSlo:
    """HPA formula on the SLO metric: ``ceil(ready * measured / target)``."""

    tolerance: float = 0.1
    name: str = "reactive-slo"

    def recommend(
        self, snapshot: MetricsSnapshot, pools: Sequence[Pool], previous: MetricsSnapshot | None
    ) -> tuple[dict[str, int], str] | None:
        out: dict[str, int] = {}
        for pool in pools:
            m = snapshot.tier(pool.name)
            if m.slo_value_seconds is None:
                return None
            ratio = m.slo_value_seconds / pool.target_seconds
            out[pool.name] = hpa_replicas(m.replicas, m.ready_replicas, ratio, self.tolerance)
        return out, "SLO metric against its target"


@dataclass(frozen=True)
class Predictive:
    """Size pools ahead of demand with the M/M/k/K admission model (tinyKube eq. 1-3).

    Demand is the *offered* rate of each class (served plus rejected), which -- unlike CPU
    utilisation, which saturates at 100 % -- shows the full size of a surge at the first read.
    The forecast for the moment a replica started now is ready (``setup + period`` ahead) is the
    measured rate plus ``noise_sigmas`` standard deviations of a Poisson count over
    ``rate_window_seconds``; with ``trend`` the rise since the previous read is extrapolated
    over that horizon too (off by default: on step changes it overshoots and the scale-down
    window then holds the overshoot). The first tier's size is searched over its bounds, later
    tiers get the fewest replicas that keep their refusals at ``1 - percentile``; the cheapest
    total that keeps both classes' rejections at ``1 - percentile`` wins, ties going to the
    earlier tier (edge first). If nothing is good enough, every pool goes to its maximum.
    ``reserve`` must match the dispatcher's (:func:`.dispatch.route`).
    """

    period_seconds: float = 5.0
    rate_window_seconds: float = 5.0
    noise_sigmas: float = 1.0
    reserve: int = 0
    trend: bool = False
    name: str = "predictive"

    def forecast(self, rate: float, before: float | None, dt: float, horizon: float) -> float:
        if self.trend and before is not None and dt > 0:
            rate += max(0.0, (rate - before) / dt) * horizon
        return rate + self.noise_sigmas * math.sqrt(max(rate, 0.0) / self.rate_window_seconds)

    def recommend(
        self, snapshot: MetricsSnapshot, pools: Sequence[Pool], previous: MetricsSnapshot | None
    ) -> tuple[dict[str, int], str] | None:
        if snapshot.private_rate is None or snapshot.normal_rate is None:
            return None
        horizon = max((p.setup_seconds for p in pools), default=0.0) + self.period_seconds
        dt = snapshot.timestamp - previous.timestamp if previous else 0.0
        lam_p = self.forecast(
            snapshot.private_rate, previous.private_rate if previous else None, dt, horizon
        )
        lam_n = self.forecast(
            snapshot.normal_rate, previous.normal_rate if previous else None, dt, horizon
        )
        sizes = size_pools(lam_p, lam_n, pools, self.reserve)
        return (
            {p.name: k for p, k in zip(pools, sizes, strict=True)},
            f"sized for {lam_p:.1f} private + {lam_n:.1f} normal requests/s",
        )


def _rest(lam_p: float, lam_n: float, pools: Sequence[Pool], reserve: int) -> list[int]:
    """Greedy sizes for ``pools`` given what is offered to the first of them."""
    sizes = []
    for pool in pools:
        offered = lam_n + (lam_p if pool.accepts_private else 0.0)
        eps = 1.0 - pool.percentile
        k = queueing.min_replicas_for_admission(
            offered,
            pool.service_rate,
            pool.target_seconds,
            eps,
            k_max=pool.max_replicas,
            delay=pool.network_delay_seconds,
        )
        k = max(pool.min_replicas, pool.max_replicas if k is None else k)
        sizes.append(k)
        plan = plan_dispatch(lam_p, lam_n, [pool.tier], [k], [pool.target_seconds], reserve)
        lam_n = plan.normal_rejected
        if pool.accepts_private:
            lam_p = plan.private_rejected
    return sizes


def size_pools(lam_p: float, lam_n: float, pools: Sequence[Pool], reserve: int) -> list[int]:
    """Fewest replicas per pool that keep each class's rejection within ``1 - percentile``."""
    if not pools:
        return []
    tiers = [p.tier for p in pools]
    targets = [p.target_seconds for p in pools]
    eps = 1.0 - max(p.percentile for p in pools)
    first = pools[0]
    best: tuple[int, list[int]] | None = None
    for k0 in range(first.max_replicas, first.min_replicas - 1, -1):
        plan0 = plan_dispatch(lam_p, lam_n, tiers[:1], [k0], targets[:1], reserve)
        left_p = plan0.private_rejected if first.accepts_private else lam_p
        sizes = [k0, *_rest(left_p, plan0.normal_rejected, pools[1:], reserve)]
        plan = plan_dispatch(lam_p, lam_n, tiers, sizes, targets, reserve)
        ok = (
            plan.private_rejected <= eps * lam_p + 1e-9
            and plan.normal_rejected <= eps * lam_n + 1e-9
        )
        if ok and (best is None or sum(sizes) < best[0]):  # ties keep the larger first tier
            best = (sum(sizes), sizes)
    if best is None:  # no size meets the SLO: give everything
        return [p.max_replicas for p in pools]
    return best[1]


def decide(
    policy: Policy,
    snapshot: MetricsSnapshot,
    pools: Sequence[Pool],
    state: ScalerState,
    *,
    behavior: Behavior | None = None,
    safety_relevant: bool = False,
) -> tuple[ScaleDecision, ScalerState]:
    """One scaling step for all pools; pure, the caller keeps the returned state."""

    def floor(pool: Pool) -> int:
        return max(pool.min_replicas, 1 if safety_relevant else 0)

    def current(pool: Pool) -> int:
        try:
            return snapshot.tier(pool.name).replicas
        except KeyError:
            return floor(pool)

    recommendation = None
    try:
        recommendation = policy.recommend(snapshot, pools, state.previous)
    except KeyError:  # a pool has no metrics at all
        recommendation = None
    if recommendation is None:
        held = state.last.replicas if state.last else {p.name: current(p) for p in pools}
        replicas = {
            p.name: min(max(held.get(p.name, current(p)), floor(p)), p.max_replicas) for p in pools
        }
        decision = ScaleDecision(
            snapshot.timestamp,
            replicas,
            "metrics unavailable: holding the last decision",
            metrics_missing=True,
        )
        return decision, replace(state, last=decision)
    wanted, reason = recommendation
    replicas = {}
    memory = dict(state.behavior)
    for pool in pools:
        lo = floor(pool)
        desired = min(max(wanted[pool.name], lo), pool.max_replicas)
        if behavior is None:
            replicas[pool.name] = desired
            continue
        step = normalize(
            desired,
            current(pool),
            memory.get(pool.name, BehaviorState()),
            behavior,
            min_replicas=lo,
            max_replicas=pool.max_replicas,
            now=snapshot.timestamp,
        )
        memory[pool.name] = step.state
        replicas[pool.name] = step.replicas
    decision = ScaleDecision(snapshot.timestamp, replicas, reason)
    return decision, ScalerState(memory, decision, snapshot)
