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
    TINYKUBE_BEHAVIOR,
    Behavior,
    PolicyType,
    ScalingPolicy,
    ScalingRules,
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

FAST_BEHAVIOR = Behavior(
    # fogfleet's predictive setting: follow the model up at once; down after 30 s, by half.
    scale_up=ScalingRules(0, (ScalingPolicy(PolicyType.PODS, 100, 1),)),
    scale_down=ScalingRules(30, (ScalingPolicy(PolicyType.PERCENT, 50, 30),)),
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


def simulate(workload: Workload, setup: _Setup, seed: int = 0) -> dict[str, float]:
    """Run one policy over the workload; returns the metrics of :data:`METRICS`."""
    rng = np.random.default_rng([seed, 1])  # only for which busy replica finishes first
    pools = [_Pool(p, ready=5) for p in setup.pools]
    tiers: list[Tier] = [p.tier for p in setup.pools]
    mus = [p.service_rate for p in setup.pools]
    delays = [p.network_delay_seconds for p in setup.pools]
    reserve = setup.reserve
    arrival, private, target, work = (
        workload.arrival,
        workload.private,
        workload.target,
        workload.work,
    )
    n = len(arrival)
    events: list[tuple[float, int, int, int]] = []  # (time, seq, kind, tier); 0=departure 1=ready
    seq = 0
    rejected_p = rejected_n = late = accepted = 0
    offered = [0, 0]  # cumulative private, normal arrivals
    rate_history: deque[tuple[float, int, int]] = deque([(0.0, 0, 0)])
    state = ScalerState()
    cpu_marks = [(0.0, 0.0, 0.0)] * len(pools)
    cpu_history: list[deque[tuple[float, float, float]]] = [deque([m]) for m in cpu_marks]
    start_of: dict[int, float] = {}
    next_tick = setup.period_seconds

    def begin(pi: int, req: int, t: float) -> None:
        nonlocal seq
        seq += 1
        start_of[req] = t
        heapq.heappush(events, (t + work[req] / mus[pi], seq, 0, pi))
        in_service[pi].append(req)

    in_service: list[list[int]] = [[] for _ in pools]

    def depart(pi: int, t: float) -> None:
        nonlocal late, accepted
        pool = pools[pi]
        pool.advance(t)
        # Service is memoryless: each running request is equally likely to finish first.
        running = in_service[pi]
        j = int(rng.integers(len(running))) if len(running) > 1 else 0
        req = running[j]
        running[j] = running[-1]
        running.pop()
        response = t - arrival[req] + delays[pi]
        accepted += 1
        late += response > target[req]
        pool.responses.append((t, response))
        if pool.draining and rng.random() < pool.draining / (pool.draining + pool.busy):
            pool.draining -= 1
        elif pool.queue:
            begin(pi, pool.queue.popleft(), t)
        else:
            pool.busy -= 1

    def became_ready(pi: int, t: float) -> None:
        pool = pools[pi]
        pool.advance(t)
        if not pool.starting or pool.starting[0] > t + 1e-9:
            return  # this start was cancelled
        pool.starting.pop(0)
        pool.ready += 1
        pool.recent_ready.append(t)
        if pool.queue:
            pool.busy += 1
            begin(pi, pool.queue.popleft(), t)

    def resize(pi: int, replicas: int, t: float) -> None:
        nonlocal seq
        pool = pools[pi]
        pool.advance(t)
        have = pool.ready + len(pool.starting)
        for _ in range(replicas - have):
            seq += 1
            ready_at = t + pool.cfg.setup_seconds
            pool.starting.append(ready_at)
            heapq.heappush(events, (ready_at, seq, 1, pi))
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

    def snapshot(t: float) -> MetricsSnapshot:
        rate_history.append((t, offered[0], offered[1]))
        while rate_history[0][0] < t - RATE_WINDOW_SECONDS - 1e-9:
            rate_history.popleft()
        t0, p0, n0 = rate_history[0]
        span = max(t - t0, 1e-9)
        out = []
        for pi, pool in enumerate(pools):
            pool.advance(t)
            hist = cpu_history[pi]
            hist.append((t, pool.busy_area, pool.ready_area))
            while hist[0][0] < t - CPU_WINDOW_SECONDS - 1e-9:
                hist.popleft()
            _, b0, r0 = hist[0]
            cpu = (pool.busy_area - b0) / (pool.ready_area - r0) if pool.ready_area > r0 else None
            while pool.recent_ready and pool.recent_ready[0] < t - CPU_WINDOW_SECONDS:
                pool.recent_ready.popleft()
            while pool.responses and pool.responses[0][0] < t - SLO_WINDOW_SECONDS:
                pool.responses.popleft()
            slo = (
                float(np.quantile([r for _, r in pool.responses], 0.9)) if pool.responses else None
            )
            out.append(
                TierMetrics(
                    pool.cfg.name,
                    replicas=pool.ready + len(pool.starting),
                    ready_replicas=max(0, pool.ready - len(pool.recent_ready)),
                    cpu_utilization=cpu,
                    slo_value_seconds=slo,
                )
            )
        return MetricsSnapshot(t, tuple(out), (offered[0] - p0) / span, (offered[1] - n0) / span)

    def tick(t: float) -> None:
        nonlocal state
        decision, state = decide(
            setup.policy, snapshot(t), setup.pools, state, behavior=setup.behavior
        )
        for pi, pool in enumerate(setup.pools):
            resize(pi, decision.replicas[pool.name], t)

    for req in range(n):
        t = float(arrival[req])
        while True:
            t_event = events[0][0] if events else math.inf
            if next_tick <= t and next_tick <= t_event:
                tick(next_tick)
                next_tick += setup.period_seconds
            elif t_event <= t:
                _, _, kind, pi = heapq.heappop(events)
                (depart if kind == 0 else became_ready)(pi, t_event)
            else:
                break
        is_private = bool(private[req])
        offered[0 if is_private else 1] += 1
        chosen = None
        for pi, pool in enumerate(pools):
            tier = tiers[pi]
            if is_private and not tier.accepts_private:
                continue
            ahead = pool.busy + len(pool.queue)
            if not is_private and tier.accepts_private:
                ahead += reserve
            estimate = estimate_response_seconds(ahead, pool.ready, mus[pi], delays[pi])
            if estimate <= target[req]:
                chosen = pi
                break
        if chosen is None:
            if is_private:
                rejected_p += 1
            else:
                rejected_n += 1
            continue
        pool = pools[chosen]
        pool.advance(t)
        if pool.busy < pool.ready:
            pool.busy += 1
            begin(chosen, req, t)
        else:
            pool.queue.append(req)
    end = float(arrival[-1])
    while events:  # drain the admitted requests; the scaler keeps running
        t_event = events[0][0]
        if next_tick <= t_event:
            tick(next_tick)
            next_tick += setup.period_seconds
            continue
        _, _, kind, pi = heapq.heappop(events)
        (depart if kind == 0 else became_ready)(pi, t_event)
        if not any(p.busy or p.queue or p.draining for p in pools):
            end = max(end, t_event)
            break
    for pool in pools:
        pool.advance(end)
    n_private = int(private.sum())
    return {
        "privacyRejected": rejected_p / max(n_private, 1),
        "normalRejected": rejected_n / max(n - n_private, 1),
        "sloViolations": float(late) / max(accepted, 1),
        "replicaSeconds": float(sum(p.replica_area for p in pools)),
    }


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
