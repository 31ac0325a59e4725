"""Seeded discrete-event benchmark of the tinyKube scenario: reactive CPU-80 % vs predictive.

Scenario (seeds/tinykube-cloud-edge-resource-management.txt, sections IV-B to IV-D):

* phases of 5000 requests each; per phase 5-50 robots and 20-100 requests/s (Poisson);
* an edge pool of at most 17 replicas (setup 1.8 s, target 0.35 s, private traffic allowed)
  and a cloud pool of at most 19 (setup 4.7 s, target 0.5 s, 15.5 ms round trip, no private
  traffic) -- Table I; both start with 5 ready replicas (IV-C);
* every request has a response-time target drawn uniformly from 0.35-0.5 s (IV-D); a robot is
  privacy-constrained with probability ``PRIVATE_ROBOT_SHARE`` and all its requests are too.

Assumptions the paper leaves open, stated so they can be challenged:

* Service times are exponential, one request at a time per replica (the M/M/k model of III-B)
  with the rate that puts the 90th percentile of an unloaded response at the tier's threshold,
  as the paper calibrated its thresholds: ``mu = ln(10) / (threshold - round trip)``. So even an
  idle pool misses a 0.35 s target for ~10 % of the requests: ``sloViolations`` has that floor.
* CPU utilisation of a replica is its busy fraction (a single-threaded service whose CPU limit
  equals its 500m request), averaged over ready, non-terminating pods over the last 15 s
  (metrics-server's resolution); pods ready for less than that count as not ready.
* Admission (III-B): a tier admits a request if tinyKube eq. 3 on its current queue meets the
  request's target (:func:`.dispatch.route`); otherwise the next tier is tried; else rejected.

Policies, same seeds and arrivals:

* ``tinykube-cpu80`` -- the baseline: HPA CPU formula at 80 % (tolerance 0.1, 15 s sync) with
  the tinyKube behaviour (+100 %/30 s, 60 s window up; -50 %/60 s, 300 s window down), through
  tinyKube's dispatcher (normal traffic may queue at the edge).
* ``cpu80-reserve`` -- the same scaler with fogfleet's dispatcher (two places of the edge
  queue reserved for private requests), to separate what routing gains from what scaling gains.
* ``reactive-slo`` -- the HPA formula on the measured p90 response time per tier (30 s
  window), 2.5 s period, fogfleet's dispatcher and behaviour.
* ``predictive`` -- fogfleet's predictive mode: offered rate per class (5 s window, 2.5 s
  period), M/M/k/K sizing at 1 % refusals per class for the tightest target (0.35 s), two
  edge places reserved for private requests, immediate scale-up, 30 s scale-down window.

Metrics per policy: ``privacyRejected`` and ``normalRejected`` (fractions of each class),
``sloViolations`` (fraction of admitted requests that exceeded their own target),
``replicaSeconds`` (integral of existing replicas, both pools, starting and terminating ones
included).
"""

from __future__ import annotations

import heapq
import math
import statistics
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from fogfleet.autoscaling.behavior import (
    FAST_BEHAVIOR,
    TINYKUBE_BEHAVIOR,
    Behavior,
)
from fogfleet.autoscaling.dispatch import Tier, estimate_response_seconds
from fogfleet.autoscaling.policy import (
    MetricsSnapshot,
    Policy,
    Pool,
    Predictive,
    ReactiveCpu,
    ReactiveSlo,
    ScalerState,
    TierMetrics,
    decide,
)

__all__ = [
    "METRICS",
    "POLICIES",
    "PRIVATE_ROBOT_SHARE",
    "Workload",
    "format_table",
    "make_workload",
    "run_benchmark",
    "simulate",
]

PRIVATE_ROBOT_SHARE = 0.3
PHASES = 12
REQUESTS_PER_PHASE = 5000
CPU_WINDOW_SECONDS = 15.0
SLO_WINDOW_SECONDS = 30.0
RATE_WINDOW_SECONDS = 5.0
PERIOD = 2.5  # fogfleet's control period in the benchmark (the HPA baseline keeps 15 s)
RESERVE = 2  # places of the edge queue kept for private requests
METRICS = ("privacyRejected", "normalRejected", "sloViolations", "replicaSeconds")

_LN10 = math.log(10.0)
EDGE = Pool("edge", 1, 17, _LN10 / 0.35, 0.35, 0.99, setup_seconds=1.8, accepts_private=True)
CLOUD = Pool(
    "cloud",
    1,
    19,
    _LN10 / (0.5 - 0.0155),
    0.5,
    0.99,
    setup_seconds=4.7,
    network_delay_seconds=0.0155,
)


@dataclass(frozen=True)
class _Setup:
    policy: Policy
    behavior: Behavior
    reserve: int
    period_seconds: float
    pools: tuple[Pool, ...]


# The predictive mode sizes for the tightest target a request may carry (0.35 s) on both tiers.
_PREDICTIVE_POOLS = (EDGE, Pool(**{**CLOUD.__dict__, "target_seconds": 0.35}))
POLICIES: dict[str, _Setup] = {
    "tinykube-cpu80": _Setup(ReactiveCpu(0.8), TINYKUBE_BEHAVIOR, 0, 15.0, (EDGE, CLOUD)),
    "cpu80-reserve": _Setup(ReactiveCpu(0.8), TINYKUBE_BEHAVIOR, RESERVE, 15.0, (EDGE, CLOUD)),
    "reactive-slo": _Setup(ReactiveSlo(), FAST_BEHAVIOR, RESERVE, PERIOD, (EDGE, CLOUD)),
    "predictive": _Setup(
        Predictive(PERIOD, RATE_WINDOW_SECONDS, reserve=RESERVE),
        FAST_BEHAVIOR,
        RESERVE,
        PERIOD,
        _PREDICTIVE_POOLS,
    ),
}


@dataclass(frozen=True)
class Workload:
    """All random draws of one seed, shared by every policy."""

    arrival: np.ndarray  # seconds, increasing
    private: np.ndarray  # bool
    target: np.ndarray  # seconds
    work: np.ndarray  # Exp(1) draws; service time on a tier = work / mu
    phases: tuple[tuple[int, float], ...]  # (robots, requests/s)


def make_workload(
    seed: int, phases: int = PHASES, requests_per_phase: int = REQUESTS_PER_PHASE
) -> Workload:
    rng = np.random.default_rng(seed)
    robot_private = rng.random(50) < PRIVATE_ROBOT_SHARE
    arrivals, private, plan = [], [], []
    start = 0.0
    for _ in range(phases):
        robots = int(rng.integers(5, 51))
        rate = float(rng.uniform(20.0, 100.0))
        gaps = rng.exponential(1.0 / rate, requests_per_phase)
        times = start + np.cumsum(gaps)
        who = rng.integers(0, robots, requests_per_phase)
        arrivals.append(times)
        private.append(robot_private[who])
        plan.append((robots, rate))
        start = float(times[-1])
    n = phases * requests_per_phase
    return Workload(
        np.concatenate(arrivals),
        np.concatenate(private),
        rng.uniform(0.35, 0.5, n),
        rng.exponential(1.0, n),
        tuple(plan),
    )


@dataclass
class _Pool:
    """Mutable simulation state of one tier."""

    cfg: Pool
    ready: int
    starting: list[float] = field(default_factory=list)  # ready times, ascending
    busy: int = 0  # ready replicas serving a request
    draining: int = 0  # terminating replicas finishing their last request
    queue: deque[int] = field(default_factory=deque)
    recent_ready: deque[float] = field(default_factory=deque)
    last_t: float = 0.0
    replica_area: float = 0.0
    busy_area: float = 0.0
    ready_area: float = 0.0
    responses: deque[tuple[float, float]] = field(default_factory=deque)

    def advance(self, t: float) -> None:
        dt = t - self.last_t
        if dt > 0:
            self.replica_area += (self.ready + len(self.starting) + self.draining) * dt
            self.busy_area += self.busy * dt
            self.ready_area += self.ready * dt
            self.last_t = t


class _Simulation:
    """One policy's run over a workload: the event queue, the pools and the scaler's state.

    Events are ``(time, seq, kind, tier)``, kind 0 a departure and 1 a replica becoming ready;
    ``seq`` keeps simultaneous events in the order they were scheduled.
    """

    def __init__(self, workload: Workload, setup: _Setup, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 1])  # only for which busy replica finishes first
        self.workload = workload
        self.setup = setup
        self.pools = [_Pool(p, ready=5) for p in setup.pools]
        self.tiers: list[Tier] = [p.tier for p in setup.pools]
        self.mus = [p.service_rate for p in setup.pools]
        self.delays = [p.network_delay_seconds for p in setup.pools]
        self.events: list[tuple[float, int, int, int]] = []
        self.seq = 0
        self.rejected_p = self.rejected_n = self.late = self.accepted = 0
        self.offered = [0, 0]  # cumulative private, normal arrivals
        self.rate_history: deque[tuple[float, int, int]] = deque([(0.0, 0, 0)])
        self.state = ScalerState()
        self.cpu_history: list[deque[tuple[float, float, float]]] = [
            deque([(0.0, 0.0, 0.0)]) for _ in self.pools
        ]
        self.in_service: list[list[int]] = [[] for _ in self.pools]
        self.next_tick = setup.period_seconds

    def begin(self, pi: int, req: int, t: float) -> None:
        self.seq += 1
        heapq.heappush(self.events, (t + self.workload.work[req] / self.mus[pi], self.seq, 0, pi))
        self.in_service[pi].append(req)

    def depart(self, pi: int, t: float) -> None:
        pool = self.pools[pi]
        pool.advance(t)
        # Service is memoryless: each running request is equally likely to finish first.
        running = self.in_service[pi]
        j = int(self.rng.integers(len(running))) if len(running) > 1 else 0
        req = running[j]
        running[j] = running[-1]
        running.pop()
        response = t - self.workload.arrival[req] + self.delays[pi]
        self.accepted += 1
        self.late += response > self.workload.target[req]
        pool.responses.append((t, response))
        if pool.draining and self.rng.random() < pool.draining / (pool.draining + pool.busy):
            pool.draining -= 1
        elif pool.queue:
            self.begin(pi, pool.queue.popleft(), t)
        else:
            pool.busy -= 1

    def became_ready(self, pi: int, t: float) -> None:
        pool = self.pools[pi]
        pool.advance(t)
        if not pool.starting or pool.starting[0] > t + 1e-9:
            return  # this start was cancelled
        pool.starting.pop(0)
        pool.ready += 1
        pool.recent_ready.append(t)
        if pool.queue:
            pool.busy += 1
            self.begin(pi, pool.queue.popleft(), t)

    def resize(self, pi: int, replicas: int, t: float) -> None:
        pool = self.pools[pi]
        pool.advance(t)
        have = pool.ready + len(pool.starting)
        for _ in range(replicas - have):
            self.seq += 1
            ready_at = t + pool.cfg.setup_seconds
            pool.starting.append(ready_at)
            heapq.heappush(self.events, (ready_at, self.seq, 1, pi))
        drop = have - replicas
        while drop > 0 and pool.starting:
            pool.starting.pop()  # newest first
            drop -= 1
        idle = min(drop, pool.ready - pool.busy)
        pool.ready -= idle
        drop -= idle
        if drop > 0:  # terminate busy replicas after their current request
            pool.ready -= drop
            pool.busy -= drop
            pool.draining += drop

    def _tier_metrics(self, pi: int, pool: _Pool, t: float) -> TierMetrics:
        pool.advance(t)
        hist = self.cpu_history[pi]
        hist.append((t, pool.busy_area, pool.ready_area))
        while hist[0][0] < t - CPU_WINDOW_SECONDS - 1e-9:
            hist.popleft()
        _, b0, r0 = hist[0]
        cpu = (pool.busy_area - b0) / (pool.ready_area - r0) if pool.ready_area > r0 else None
        while pool.recent_ready and pool.recent_ready[0] < t - CPU_WINDOW_SECONDS:
            pool.recent_ready.popleft()
        while pool.responses and pool.responses[0][0] < t - SLO_WINDOW_SECONDS:
            pool.responses.popleft()
        slo = float(np.quantile([r for _, r in pool.responses], 0.9)) if pool.responses else None
        return TierMetrics(
            pool.cfg.name,
            replicas=pool.ready + len(pool.starting),
            ready_replicas=max(0, pool.ready - len(pool.recent_ready)),
            cpu_utilization=cpu,
            slo_value_seconds=slo,
        )

    def snapshot(self, t: float) -> MetricsSnapshot:
        self.rate_history.append((t, self.offered[0], self.offered[1]))
        while self.rate_history[0][0] < t - RATE_WINDOW_SECONDS - 1e-9:
            self.rate_history.popleft()
        t0, p0, n0 = self.rate_history[0]
        span = max(t - t0, 1e-9)
        tiers = tuple(self._tier_metrics(pi, pool, t) for pi, pool in enumerate(self.pools))
        return MetricsSnapshot(
            t, tiers, (self.offered[0] - p0) / span, (self.offered[1] - n0) / span
        )

    def tick(self, t: float) -> None:
        setup = self.setup
        decision, self.state = decide(
            setup.policy, self.snapshot(t), setup.pools, self.state, behavior=setup.behavior
        )
        for pi, pool in enumerate(setup.pools):
            self.resize(pi, decision.replicas[pool.name], t)

    def _pop_event(self) -> None:
        t_event, _, kind, pi = heapq.heappop(self.events)
        (self.depart if kind == 0 else self.became_ready)(pi, t_event)

    def catch_up(self, t: float) -> None:
        """Every scaler tick and event up to the arrival at ``t``, in time order."""
        while True:
            t_event = self.events[0][0] if self.events else math.inf
            if self.next_tick <= t and self.next_tick <= t_event:
                self.tick(self.next_tick)
                self.next_tick += self.setup.period_seconds
            elif t_event <= t:
                self._pop_event()
            else:
                break

    def _route(self, req: int, is_private: bool) -> int | None:
        """The first tier whose estimate meets the request's target (None: rejected)."""
        for pi, pool in enumerate(self.pools):
            tier = self.tiers[pi]
            if is_private and not tier.accepts_private:
                continue
            ahead = pool.busy + len(pool.queue)
            if not is_private and tier.accepts_private:
                ahead += self.setup.reserve
            estimate = estimate_response_seconds(ahead, pool.ready, self.mus[pi], self.delays[pi])
            if estimate <= self.workload.target[req]:
                return pi
        return None

    def admit(self, req: int) -> None:
        """Route the request arriving now, then serve, queue or reject it."""
        t = float(self.workload.arrival[req])
        is_private = bool(self.workload.private[req])
        self.offered[0 if is_private else 1] += 1
        chosen = self._route(req, is_private)
        if chosen is None:
            if is_private:
                self.rejected_p += 1
            else:
                self.rejected_n += 1
            return
        pool = self.pools[chosen]
        pool.advance(t)
        if pool.busy < pool.ready:
            pool.busy += 1
            self.begin(chosen, req, t)
        else:
            pool.queue.append(req)

    def drain(self) -> float:
        """Serve the admitted requests (the scaler keeps running); the run's end time."""
        end = float(self.workload.arrival[-1])
        while self.events:
            t_event = self.events[0][0]
            if self.next_tick <= t_event:
                self.tick(self.next_tick)
                self.next_tick += self.setup.period_seconds
                continue
            self._pop_event()
            if not any(p.busy or p.queue or p.draining for p in self.pools):
                end = max(end, t_event)
                break
        for pool in self.pools:
            pool.advance(end)
        return end

    def results(self) -> dict[str, float]:
        n = len(self.workload.arrival)
        n_private = int(self.workload.private.sum())
        return {
            "privacyRejected": self.rejected_p / max(n_private, 1),
            "normalRejected": self.rejected_n / max(n - n_private, 1),
            "sloViolations": float(self.late) / max(self.accepted, 1),
            "replicaSeconds": float(sum(p.replica_area for p in self.pools)),
        }


def simulate(workload: Workload, setup: _Setup, seed: int = 0) -> dict[str, float]:
    """Run one policy over the workload; returns the metrics of :data:`METRICS`."""
    run = _Simulation(workload, setup, seed)
    for req in range(len(workload.arrival)):
        run.catch_up(float(workload.arrival[req]))
        run.admit(req)
    run.drain()
    return run.results()


def run_benchmark(seed: int) -> dict[str, dict[str, float]]:
    """Every policy of :data:`POLICIES` on the workload of ``seed``; keyed by policy name."""
    workload = make_workload(seed)
    return {name: simulate(workload, setup, seed) for name, setup in POLICIES.items()}


def format_table(results_by_seed: Mapping[int, Mapping[str, Mapping[str, float]]]) -> str:
    """Medians over seeds, one row per metric, one column per policy."""
    if not results_by_seed:
        return "(no results)"
    runs = list(results_by_seed.values())
    policies: Sequence[str] = list(runs[0])
    header = [f"metric (median of {len(runs)} seeds)", *policies]
    rows = [header]
    for metric in METRICS:
        cells = [metric]
        for policy in policies:
            value = statistics.median(run[policy][metric] for run in runs)
            cells.append(f"{value:.0f}" if metric == "replicaSeconds" else f"{value:.2%}")
        rows.append(cells)
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = [
        "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        )
        for r in rows
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
