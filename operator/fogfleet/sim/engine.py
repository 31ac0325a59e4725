"""Exact event-driven simulation of the cycles of the instances placed on one node.

Nodes do not interact (transfers are pure delays), so each node is simulated on its own.

A cycle of instance i (eq. 4) starts at ``s``: input transfer ``d_in``, then execution of
``work`` seconds (its uncontended time at cpu_use cores), then output transfer ``d_out``. It
misses when its duration exceeds cycle[i]. The next cycle starts at max(s + cycle, end), or at
the start of the next on-episode if the instance is inactive then. Only cycles that start
before the horizon are run; they are run to completion (at most one per instance runs past it).

CPU sharing: a running job demands ``cpu_use`` cores. While the demands on the node fit its
capacity every job gets its demand. Otherwise the capacity is water-filled in proportion to the
jobs' weights, as Linux's CFS shares a busy CPU by ``cpu.shares`` (which the kubelet sets from
the pod's CPU request): each job gets min(demand, level x weight), the level chosen so that the
shares sum to the capacity. A job with share ``a`` progresses at rate ``a / cpu_use``. Between
two events (an execution start or end) the shares are constant, so completion times are exact
(processor sharing, no time step). Equal weights give max-min fairness; measured on the bed's
real nodes (``make bench-real``), an unweighted model put plain Deployments' small-request
modules far ahead of where CFS puts them.

**How the kernel spreads a shortage** (issue 49, ``spread``). Processor sharing stretches every
running cycle alike, so a node short of CPU by a fifth makes every cycle on it late. The
kernel does not: it favours a task that wakes after sleeping over the tasks that have run
without a break (CFS's sleeper credit; EEVDF keeps the lag a sleeping task is owed), and a module
paced at its row's rate sleeps between its slices while it keeps pace and spins without a
break once it falls behind. The job that has just begun executing therefore keeps its pace,
and the shortage lands on the cycles already running late. ``spread`` is the fraction of the
capacity given that way, latest job first, each up to its demand (``newest_first``); the rest is
shared as above. 0 is processor sharing alone (the declared model); the real-node benchmark
fits it on a pilot (``e2e.bench.real.fit``). Shares stay constant between events, so the
simulation stays exact.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

from .episodes import Episodes

__all__ = ["Track", "newest_first", "run_independent", "run_shared", "water_fill"]

_EPS = 1e-12


@dataclass(slots=True)
class Track:
    """One placed instance: its pre-drawn samples, its episodes and its cycle records."""

    cycle: float  # expected cycle time T, seconds
    demand: float  # cpu_use, cores
    work: list[float]  # execution time of cycle n at full share, seconds
    d_in: list[float]  # input transfer of cycle n, seconds
    d_out: list[float]  # output transfer of cycle n, seconds
    episodes: Episodes
    horizon: float
    durations: list[float] = field(default_factory=list)
    missed: int = 0
    n: int = -1  # index of the cycle in flight
    start: float = 0.0  # its start time
    _ep: int = 0  # first on-episode that may still contain a future start
    weight: float = 1.0  # CFS weight under contention: the CPU request

    def _next_start(self, t: float) -> float:
        """Earliest time >= t at which the instance is active (inf: never again)."""
        starts, ends = self.episodes
        k = self._ep
        while k < len(ends) and ends[k] <= t:
            k += 1
        self._ep = k
        if k == len(ends):
            return math.inf
        return max(t, starts[k])

    def _begin(self, t: float) -> float:
        """Start a cycle at the first active time >= t; return when its execution begins."""
        s = self._next_start(t)
        if s >= self.horizon or self.n + 1 >= len(self.work):
            return math.inf
        self.n += 1
        self.start = s
        return s + self.d_in[self.n]

    def first_arrival(self) -> float:
        return self._begin(0.0)

    def complete(self, t_exec_end: float) -> float:
        """Record the cycle whose execution ended at ``t_exec_end``; return the next arrival."""
        end = t_exec_end + self.d_out[self.n]
        duration = end - self.start
        self.durations.append(duration)
        if duration > self.cycle:
            self.missed += 1
        return self._begin(max(self.start + self.cycle, end))


def _overlap(a: float, b: float, horizon: float) -> float:
    return max(0.0, min(b, horizon) - min(a, horizon))


def run_independent(track: Track) -> float:
    """Cycles of an instance that never waits for CPU (its node's demands always fit).

    Returns the busy core-seconds within the horizon.
    """
    busy = 0.0
    t = track.first_arrival()
    while t < math.inf:
        x = track.work[track.n]
        busy += track.demand * _overlap(t, t + x, track.horizon)
        t = track.complete(t + x)
    return busy


def water_fill(
    demands: list[float], capacity: float, weights: list[float] | None = None
) -> list[float]:
    """Shares of ``capacity`` cores, each ``min(demand, level x weight)`` (weighted max-min
    fair; equal weights without ``weights``); a share never exceeds its demand."""
    if sum(demands) <= capacity:
        return list(demands)
    w = weights if weights is not None else [1.0] * len(demands)
    w = [max(x, _EPS) for x in w]
    shares = [0.0] * len(demands)
    rest, weight_left = capacity, sum(w)
    order = sorted(range(len(demands)), key=lambda k: demands[k] / w[k])
    for pos, k in enumerate(order):
        if demands[k] * weight_left <= rest * w[k]:  # capped by its demand at this level
            shares[k] = demands[k]
            rest -= demands[k]
            weight_left -= w[k]
        else:
            level = rest / weight_left
            for k2 in order[pos:]:
                shares[k2] = level * w[k2]
            break
    return shares


def newest_first(demands: list[float], capacity: float, woke: list[float]) -> list[float]:
    """Shares of ``capacity`` cores given to the jobs in the order they began executing,
    the latest first, each up to its demand (ties: the later job in the list first)."""
    shares = [0.0] * len(demands)
    rest = capacity
    for k in sorted(range(len(demands)), key=lambda k: (woke[k], k), reverse=True):
        shares[k] = min(demands[k], rest)
        rest -= shares[k]
    return shares


def _shares(
    dem: list[float], capacity: float, wts: list[float], woke: list[float], spread: float
) -> list[float]:
    """The running jobs' shares of a node short of CPU (module docstring)."""
    fair = water_fill(dem, capacity, wts)
    if spread <= 0.0:
        return fair
    first = newest_first(dem, capacity, woke)
    return [(1.0 - spread) * a + spread * b for a, b in zip(fair, first, strict=True)]


def run_shared(tracks: list[Track], capacity: float, horizon: float, spread: float = 0.0) -> float:
    """Processor sharing of ``capacity`` cores among the tracks' executions, with ``spread``
    of it given to the job that began executing last first (module docstring).

    Event loop: a heap of pending execution starts (at most one per track) and the running jobs
    (few, kept in plain lists); the shares are recomputed only when the job set changes.
    Returns the busy core-seconds within the horizon.
    """
    if not 0.0 <= spread <= 1.0:
        raise ValueError(f"spread must lie in [0, 1], got {spread}")
    heap = [(t, k) for k, tr in enumerate(tracks) if (t := tr.first_arrival()) < math.inf]
    heapq.heapify(heap)
    jobs: list[int] = []  # running track indices
    dem: list[float] = []  # their demands, cores
    wts: list[float] = []  # their weights
    woke: list[float] = []  # when each began executing its cycle
    rem: list[float] = []  # remaining work, seconds at full share
    rate: list[float] = []  # progress per second (share / demand)
    load = 0.0  # sum of shares, cores
    now = 0.0
    busy = 0.0
    while heap or jobs:
        best = math.inf
        first = -1
        for idx, r in enumerate(rem):
            dt = r / rate[idx] if rate[idx] > 0.0 else math.inf  # newest_first may give 0
            if dt < best:
                best, first = dt, idx
        t_arr = heap[0][0] if heap else math.inf
        completing = now + best <= t_arr  # on a tie, the completion goes first
        t_next = now + best if completing else t_arr
        dt = t_next - now
        if now < horizon:
            busy += load * (min(t_next, horizon) - now)
        rem = [r - q * dt for r, q in zip(rem, rate, strict=True)]
        now = t_next
        if completing:
            rem[first] = 0.0
            done = [idx for idx, r in enumerate(rem) if r <= _EPS]
            for idx in done:
                k = jobs[idx]
                t_a = tracks[k].complete(now)
                if t_a < math.inf:
                    heapq.heappush(heap, (t_a, k))
            keep = [idx for idx, r in enumerate(rem) if r > _EPS]
            jobs = [jobs[idx] for idx in keep]
            dem = [dem[idx] for idx in keep]
            wts = [wts[idx] for idx in keep]
            woke = [woke[idx] for idx in keep]
            rem = [rem[idx] for idx in keep]
        else:
            _, k = heapq.heappop(heap)
            jobs.append(k)
            dem.append(tracks[k].demand)
            wts.append(tracks[k].weight)
            woke.append(now)
            rem.append(tracks[k].work[tracks[k].n])
        if sum(dem) <= capacity:
            rate = [1.0] * len(dem)
            load = sum(dem)
        else:
            shares = _shares(dem, capacity, wts, woke, spread)
            rate = [a / d for a, d in zip(shares, dem, strict=True)]
            load = capacity
    return busy
