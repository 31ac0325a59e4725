"""Constructive plans that seed the search: greedy best-fit by miss probability, on-board
first, spread. Each places instances one at a time (largest CPU request first) on an allowed
node with room, so each is feasible whenever a greedy packing exists."""

from __future__ import annotations

import time
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Allocation, Problem

from .objectives import UPLINK_SHARE, feasible, miss_probability, objective_values
from .schedule import Schedule

__all__ = ["Fit", "best_uncontended_miss", "greedy", "greedy_schedule", "uncontended_miss"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def uncontended_miss(
    problem: Problem,
    allocation: Allocation,
    rows: NDArray[np.int64] | None = None,
    nodes: NDArray[np.int64] | None = None,
) -> F64:
    """P(t_cycle > T) of each (instance, node) pair without contention (I, N), or of the
    instances ``rows`` only (R, N), or of the pairs (rows[k], nodes[k]) (R,); 1 where not
    allowed. Uses the same normal model as ``objectives.missRate`` at slowdown 1."""
    r: Any = slice(None) if rows is None else rows
    at: Any = r if nodes is None else (r, nodes)
    allowed = problem.allowed[at]
    exe = np.where(allowed, allocation.exe_mean[at], 0.0)
    net_mean, net_std = problem.net_mean[at], problem.net_std[at]
    sd = np.sqrt(np.where(allowed, allocation.exe_std[at], 0.0) ** 2 + net_std**2)
    cycle = problem.cycle[r] if nodes is not None else problem.cycle[r][:, None]
    cycle = np.broadcast_to(cycle, exe.shape)
    q = miss_probability(net_mean + exe, sd, cycle)
    return np.where(allowed, q, 1.0)


def best_uncontended_miss(problem: Problem, allocation: Allocation, rows: NDArray[np.int64]) -> F64:
    """The lowest ``uncontended_miss`` of each instance ``rows`` over its allowed nodes (R,);
    1 where none is allowed. The same values as ``uncontended_miss(problem, allocation,
    rows).min(axis=1)`` at a fraction of the work: an instance may use the shared (edge and
    cloud) nodes but, of the robots' computers, usually only its own, so the table is computed
    over the shared nodes and the allowed robot pairs, whichever they are, are added one by one
    (at 1000 robots 401 of 1401 columns: 2364 instances in 0.07 s instead of 0.11 s)."""
    rows = np.asarray(rows, dtype=np.int64)
    best = np.ones(len(rows))
    if not len(rows):
        return best
    shared = np.flatnonzero(problem.tier > 0)
    if shared.size:
        q = uncontended_miss(problem, allocation, rows[:, None], shared[None, :])
        best = np.minimum(best, q.min(axis=1))
    robots = np.flatnonzero(problem.tier == 0)
    k, c = np.nonzero(problem.allowed[rows[:, None], robots[None, :]])
    if k.size:
        np.minimum.at(best, k, uncontended_miss(problem, allocation, rows[k], robots[c]))
    return best


def _preference(q: F64, ratio: F64) -> F64:
    """A node's preference for an instance (lower is better): its miss probability ``q``,
    then its cycle ratio (latency over the cycle, capped at 10) as a tie-break."""
    return q + 0.01 * np.minimum(ratio, 10.0)


class Fit:
    """Per (instance, node) demands and per node capacities used by greedy and repair.

    The (I, N) tables are computed on first use; the ``*_rows`` methods give the same values
    for a few instances without them (an incremental re-plan of a 1000-robot fleet looks at
    a hundred instances, not 11 million pairs)."""

    def __init__(self, problem: Problem, allocation: Allocation, dense: bool = True) -> None:
        self.problem = problem
        self.allocation = allocation
        self.dense = dense  # pair tables from the (I, N) tables (a search builds them anyway)
        self.cap = np.asarray(problem.capacity, dtype=np.float64)
        self.robots = problem.tier == 0
        self.uplink = UPLINK_SHARE * problem.uplink_bandwidth

    @cached_property
    def share(self) -> F64:
        """(I, 3) each instance's share of its robot's ``reserve`` (``Problem.fallback_share``)."""
        return self.problem.fallback_share(self.allocation)

    @cached_property
    def reserve(self) -> F64:
        """(N, 3) what each robot holds for on-board fallbacks whatever the plan
        (``Problem.fallback_reserve``): every load summed from ``demand`` starts from it."""
        return self.problem.fallback_reserve(self.allocation)

    def demand_rows(self, rows: NDArray[np.int64]) -> F64:
        """(R, N, 3) cpu request, memory, gpus of the instances ``rows`` on every node (on its
        home node an instance with a fallback needs only what its ``share`` does not cover)."""
        p = self.problem
        out = np.empty((len(rows), p.n_nodes, 3))
        out[:, :, 0] = self.allocation.cpu_request[rows]
        out[:, :, 1] = p.memory[rows][:, None]
        out[:, :, 2] = p.gpu[rows][:, None]
        held = p.held_at_home[rows]
        if held.any():  # their share at home is in ``reserve``
            out[np.flatnonzero(held), p.home[rows[held]], :] -= self.share[rows[held]]
        return out

    def demand_at(self, rows: NDArray[np.int64], nodes: NDArray[np.int64]) -> F64:
        """(R, 3) what instance ``rows[k]`` needs on node ``nodes[k]``."""
        p = self.problem
        cpu = self.allocation.cpu_request[rows, nodes]
        out = np.stack([cpu, p.memory[rows], p.gpu[rows]], axis=1)
        held = p.held_at_home[rows] & (nodes == p.home[rows])
        out[held] -= self.share[rows[held]]  # in ``reserve``
        return out

    def pref_rows(self, rows: NDArray[np.int64], q: F64 | None = None) -> F64:
        """(R, N) the preference among allowed nodes: low miss probability, then low cycle
        ratio (latency); inf where not allowed. ``q``: ``uncontended_miss`` of those rows."""
        p = self.problem
        allowed = p.allowed[rows]
        if q is None:
            q = uncontended_miss(p, self.allocation, rows)
        t = (p.net_mean[rows] + np.where(allowed, self.allocation.exe_mean[rows], 0.0)) / p.cycle[
            rows
        ][:, None]
        return np.where(allowed, _preference(q, t), np.inf)

    @cached_property
    def demand(self) -> F64:
        return self.demand_rows(np.arange(self.problem.n_instances))

    @cached_property
    def q(self) -> F64:
        return uncontended_miss(self.problem, self.allocation)

    @cached_property
    def pref(self) -> F64:
        return self.pref_rows(np.arange(self.problem.n_instances), self.q)

    @cached_property
    def pairs(self) -> tuple[I64, I64]:
        """The allowed (instance, node) pairs, by instance then node (``np.nonzero``)."""
        rows, cols = np.nonzero(self.problem.allowed)
        return rows.astype(np.int64), cols.astype(np.int64)

    # The pair tables hold the (I, N) tables' values on the allowed pairs. A search builds the
    # whole tables anyway and they are read from them; a packing alone (``degrade.packs``, a
    # greedy plan per try: ``dense=False``) computes them on the pairs only: at 1000 robots
    # ~400 of 1400 columns, without the (I, N, 3) demand table (270 MB).

    @cached_property
    def pair_demand(self) -> F64:
        """(P, 3) ``demand`` of each allowed pair."""
        rows, cols = self.pairs
        return self.demand[rows, cols] if self.dense else self.demand_at(rows, cols)

    @cached_property
    def pair_q(self) -> F64:
        """(P,) ``q`` of each allowed pair."""
        rows, cols = self.pairs
        if self.dense:
            return self.q[rows, cols]
        return uncontended_miss(self.problem, self.allocation, rows, cols)

    @cached_property
    def pair_pref(self) -> F64:
        """(P,) ``pref`` of each allowed pair (``pref_rows``' formula on the pairs)."""
        rows, cols = self.pairs
        if self.dense:
            return self.pref[rows, cols]
        p = self.problem
        t = (p.net_mean[rows, cols] + self.allocation.exe_mean[rows, cols]) / p.cycle[rows]
        return _preference(self.pair_q, t)

    @cached_property
    def order(self) -> NDArray[np.int64]:
        """Instances by their largest CPU request on an allowed node, largest first."""
        req = np.where(self.problem.allowed, self.allocation.cpu_request, 0.0)
        return np.argsort(-req.max(axis=1), kind="stable").astype(np.int64)


def greedy(
    problem: Problem, allocation: Allocation, style: str = "best-fit", fit: Fit | None = None
) -> I64:
    """One plan: ``best-fit`` (lowest miss probability, ties to the fullest node that fits),
    ``spread`` (ties to the emptiest), ``level`` (the emptiest node among those with a miss
    probability within 1e-3 of the lowest: keeps the peak utilisation low), ``onboard``
    (the home robot whenever it fits, else
    best-fit). Instances with an empty gene space get -1; if nothing fits, the allowed node
    with the smallest overload is used (the repair may fix it later)."""
    f = fit or Fit(problem, allocation)
    n_n = problem.n_nodes
    used = f.reserve.copy()
    up = np.zeros(n_n)
    x = np.full(problem.n_instances, -1, dtype=np.int64)
    # each instance looks only at its allowed nodes (ascending, so ties go to the lowest
    # node as an argmin over all nodes would): at 1000 robots ~400 of 1400 columns
    rows, cols = f.pairs
    starts = np.searchsorted(rows, np.arange(problem.n_instances + 1))
    # what the loop reads of each (instance, allowed node) pair, gathered once: slices of
    # these are views, where indexing the (I, N) tables per instance copied
    pair_demand = f.pair_demand
    pair_cap = f.cap[cols]
    pair_pref = f.pair_pref if style != "level" else pair_cap[:, 0]
    pair_q = f.pair_q if style == "level" else pair_cap[:, 0]
    for i in f.order:
        a, b = starts[i], starts[i + 1]
        if a == b:
            continue
        c = cols[a:b]
        d = pair_demand[a:b]
        after = used[c] + d
        cap = pair_cap[a:b]
        room = np.all(after <= cap + 1e-9, axis=1)
        h = int(problem.home[i])
        if h >= 0 and problem.traffic[i] > 0:
            over = up[h] + problem.traffic[i] > f.uplink[h] + 1e-9
            if over:
                room &= c == h
        util = np.max(after / np.maximum(cap, 1e-9), axis=1)
        at_home = np.flatnonzero(c == h) if h >= 0 else c[:0]
        if style == "onboard" and len(at_home) and room[at_home[0]]:
            k = int(at_home[0])
        elif style == "level" and room.any():
            # min-max: the emptiest node among those within 1e-3 of the lowest miss probability
            q = pair_q[a:b]
            qmin = float(np.min(np.where(room, q, np.inf)))
            k = int(np.argmin(np.where(room & (q <= qmin + 1e-3), util, np.inf)))
        elif room.any():
            tie = -1e-3 * util if style in ("best-fit", "onboard") else 0.05 * util
            score = np.where(room, pair_pref[a:b] + tie, np.inf)
            k = int(np.argmin(score))
        else:
            k = int(np.argmin(util))  # the smallest overload
        j = int(c[k])
        x[i] = j
        used[j] += d[k]
        if h >= 0 and j != h:
            up[h] += problem.traffic[i]
    return x


def greedy_schedule(problem: Problem, settings: SchedulerSettings) -> Schedule:
    """The first feasible of the greedy plans (best-fit, spread, on-board), as a Schedule: a
    fast deterministic planner for tests and for a first answer."""
    t0 = time.perf_counter()
    names = [o.value for o in settings.objectives]
    for style in ("best-fit", "spread", "onboard"):
        x = greedy(problem, problem.limits, style)
        if feasible(problem, x, True):
            break
    values = objective_values(problem, x, True, names)
    return Schedule(
        scheduler="greedy",
        placement=x,
        with_limits=True,
        objectives=values,
        feasible=feasible(problem, x, True) and not problem.reasons,
        duration_seconds=time.perf_counter() - t0,
        choice_reason=f"greedy {style}",
        objective_names=tuple(names),
        reasons=dict(problem.reasons),
    )
