"""The twin's pure core: a shared service's request queue, stepped in (wall-clock) time.

Each pool (tier) is an M/M/k queue of tinyKube III-B: Poisson arrivals, exponential service
at ``service_rate`` per replica, ``k`` = the pool's *ready* replicas (pods Running for longer
than the pool's setup time). Every arrival is admitted by :func:`fogfleet.autoscaling.dispatch
.route` -- the dispatcher the predictive scaler sizes for, with the same ``reserve`` -- or
rejected (``reason="capacity"`` when no allowed pool has a replica, else ``"slo"``). A
request's response time is its time in the queue and in service plus the pool's network round
trip. When replicas go away, requests in service finish (the pod drains) and the queue waits.

:meth:`ServiceSim.advance` simulates from the last instant to ``until`` at the given arrival
rates and returns what happened, as records the exporter turns into the contract metrics;
it does no I/O and draws only from its own seeded generator.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fogfleet.autoscaling.dispatch import Tier, TierLoad, route
from fogfleet.autoscaling.policy import Pool

__all__ = ["Rejected", "Served", "ServiceSim"]


@dataclass(frozen=True)
class Served:
    tier: str
    private: bool
    response_seconds: float
    target_seconds: float = math.inf  # the request's own response-time target

    @property
    def late(self) -> bool:
        """Answered after its own target: an SLO violation (tinyKube IV-D)."""
        return self.response_seconds > self.target_seconds


@dataclass(frozen=True)
class Rejected:
    private: bool
    reason: str  # "slo" | "capacity"


@dataclass
class _PoolState:
    cfg: Pool
    ready: int = 0
    starting: int = 0
    busy: list[tuple[float, int]] = field(default_factory=list)  # heap of (end, request id)
    queue: deque[int] = field(default_factory=deque)

    @property
    def in_system(self) -> int:
        return len(self.busy) + len(self.queue)


class ServiceSim:
    """One shared service (all its pools), simulated request by request."""

    def __init__(self, pools: Sequence[Pool], *, seed: int = 0, reserve: int = 0) -> None:
        if not pools:
            raise ValueError("a service needs at least one pool")
        self.pools = [_PoolState(p) for p in pools]
        self.tiers: list[Tier] = [p.tier for p in pools]
        self.reserve = reserve
        self.rng = np.random.default_rng(seed)
        self.now = 0.0
        self._next_arrival: float | None = None
        self._arrivals: dict[int, tuple[float, bool, float]] = {}  # arrival, private, target
        self._seq = 0
        lo = min(p.target_seconds for p in pools)
        hi = max(p.target_seconds for p in pools)
        self._targets = (lo, hi)

    # ------------------------------------------------------------------ state
    def reconfigure(self, pools: Sequence[Pool]) -> None:
        """New pool settings (the module's spec changed); queues and counts are kept."""
        by_name = {p.cfg.name: p for p in self.pools}
        self.pools = [
            _PoolState(
                cfg, by_name[cfg.name].ready, by_name[cfg.name].starting,
                by_name[cfg.name].busy, by_name[cfg.name].queue,
            )
            if cfg.name in by_name
            else _PoolState(cfg)
            for cfg in pools
        ]  # fmt: skip
        self.tiers = [p.tier for p in pools]
        self._targets = (
            min(p.target_seconds for p in pools),
            max(p.target_seconds for p in pools),
        )

    def set_replicas(self, tier: str, ready: int, starting: int = 0) -> None:
        """Ready (serving) and starting replicas of a pool; unknown tiers are ignored."""
        for pool in self.pools:
            if pool.cfg.name == tier:
                pool.ready, pool.starting = max(0, ready), max(0, starting)

    def queue_length(self, tier: str) -> int:
        return next((p.in_system for p in self.pools if p.cfg.name == tier), 0)

    def replicas(self, tier: str) -> tuple[int, int]:
        return next(((p.ready, p.starting) for p in self.pools if p.cfg.name == tier), (0, 0))

    # ------------------------------------------------------------------ simulation
    def _start_waiting(self, pool: _PoolState, t: float) -> None:
        while pool.queue and len(pool.busy) < pool.ready:
            req = pool.queue.popleft()
            end = t + float(self.rng.exponential(1.0 / pool.cfg.service_rate))
            heapq.heappush(pool.busy, (end, req))

    def _depart(self, pool: _PoolState, out: list[Served | Rejected]) -> None:
        end, req = heapq.heappop(pool.busy)
        arrived, private, target = self._arrivals.pop(req)
        response = end - arrived + pool.cfg.network_delay_seconds
        out.append(Served(pool.cfg.name, private, response, target))
        self._start_waiting(pool, end)

    def _arrive(self, t: float, private: bool, out: list[Served | Rejected]) -> None:
        loads = [TierLoad(p.ready, p.in_system) for p in self.pools]
        target = float(self.rng.uniform(*self._targets))
        chosen = route(private, target, self.tiers, loads, self.reserve)
        if chosen is None:
            allowed = [p for p, tier in zip(self.pools, self.tiers, strict=True)
                       if tier.accepts_private or not private]  # fmt: skip
            reason = "slo" if any(p.ready > 0 for p in allowed) else "capacity"
            out.append(Rejected(private, reason))
            return
        pool = self.pools[chosen]
        self._seq += 1
        self._arrivals[self._seq] = (t, private, target)
        pool.queue.append(self._seq)
        self._start_waiting(pool, t)

    def advance(
        self, until: float, private_rate: float, normal_rate: float
    ) -> list[Served | Rejected]:
        """Simulate up to ``until`` (seconds) at the given arrival rates (requests/s)."""
        out: list[Served | Rejected] = []
        total = max(private_rate, 0.0) + max(normal_rate, 0.0)
        if until <= self.now:
            return out
        for pool in self.pools:  # replicas may have been added since the last step
            self._start_waiting(pool, self.now)
        if total <= 0:
            self._next_arrival = None
        elif self._next_arrival is None or self._next_arrival < self.now:
            self._next_arrival = self.now + float(self.rng.exponential(1.0 / total))
        while True:
            next_dep = min(
                ((p.busy[0][0], i) for i, p in enumerate(self.pools) if p.busy),
                default=(math.inf, -1),
            )
            arrival = self._next_arrival if self._next_arrival is not None else math.inf
            t = min(next_dep[0], arrival)
            if t > until:
                break
            if next_dep[0] <= arrival:
                self._depart(self.pools[next_dep[1]], out)
            else:
                private = bool(self.rng.random() < private_rate / total)
                self._arrive(t, private, out)
                self._next_arrival = t + float(self.rng.exponential(1.0 / total))
        self.now = until
        # An arrival drawn beyond ``until`` stays valid only if the rate does not change; the
        # memoryless property lets the next step redraw it at its own rate.
        self._next_arrival = None
        return out
