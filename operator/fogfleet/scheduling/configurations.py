"""Robot configurations: the robot bound on S and the plan its prices give (issue 46).

A robot's own instances compete with other robots only through the edge and cloud capacity.
Each robot picks one *configuration*, the set of its instances that run on board, within its
capacity and uplink share; its peak utilisation u is a constant of the configuration.
Off board, the reserve z of S (``exact``'s module docstring; F2, eq. 2) is at least the
requested CPU summed over the edge and cloud nodes over their capacity (a peak is at least
the mean). Pricing that CPU at lambda in [0, w_reserve] (a Lagrange multiplier on the
shared capacity) separates the robots, so for every threshold t on the robots' peaks

    S >= sum over robots of the cheapest configuration with u <= t at lambda
         + (w_reserve - lambda) t                                          (weak duality)

``robot_dual`` computes the largest such bound, the *robot bound*: the LP relaxation may put a
fraction of a 4-core module on a 6-core robot and hold every node at one peak, so on the
1000-robot bench fleet the robot bound is 3-4 % above ``exact.lp_bound``.

``priced_plans`` is the Lagrangian heuristic of the same dual: every robot takes its cheapest
configuration at the price and threshold where the bound is attained, and what runs off
board is packed on the edge and cloud nodes by the LPT rule of ``levelling`` (most
constrained, then largest first, each on the node whose peak after it is lowest). The bound
prices off-board CPU as if it spread perfectly; the packing pays only its imbalance. On the
1000-robot bench fleet the search with it ends 0.4-1.5 % above the bound on seeds 1-5, where
NSGA-II's warm start alone ended 1.3-3.2 % above it (``fogfleet bench scale-plan``).
``with_priced`` adds it to the search's archive before the levelling (which a warm-started
fleet with a priced plan skips, ``solver.nsga2``) and the Pareto local search that polishes
the archive.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem

from .exact import DEFAULT_WEIGHTS, LINEAR, pair_costs
from .heuristics import Fit
from .levelling import MISS_TOLERANCE, node_peaks, pack_off_board
from .objectives import UPLINK_SHARE
from .problem import PlacementProblem

__all__ = ["RobotDual", "priced_plans", "robot_bound", "robot_dual", "with_priced"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

MAX_ON_BOARD = 12  # a robot's instances whose on/off-board configurations robot_dual lists
LAMBDA_STEPS = 41  # prices of off-board CPU robot_dual tries (any price gives a bound)
MAX_THRESHOLDS = 64  # robot peaks it tries (fewer: each interval counts its lower end)
EPS = 1e-12
ROUNDS = 2  # configurations chosen again under the off-board peak at most once


@dataclass(frozen=True)
class _Group:
    """The robots with the same number of own instances, and their configurations."""

    robots: I64  # (R,) node indices
    instances: I64  # (R, s) each robot's own instances
    configs: NDArray[np.bool_]  # (K, s) which of them run on board
    peaks: F64  # (R, K) each configuration's peak utilisation; inf where it does not fit
    costs: F64  # (L, R, K) its cost at each price: on board as placed, off board cheapest


@dataclass(frozen=True)
class RobotDual:
    """The robot bound and where it is attained: the price ``lambdas[price]`` and the
    threshold ``below`` (configurations with a peak under it)."""

    bound: float
    price: int
    below: float
    groups: tuple[_Group, ...]

    @property
    def prices(self) -> int:
        """How many prices the dual tried (the last is the reserve's weight)."""
        return int(self.groups[0].costs.shape[0]) if self.groups else 1

    def on_board(
        self, n_instances: int, price: int | None = None, below: float | None = None
    ) -> I64 | None:
        """Each instance's robot where the configurations cheapest at ``price`` among those
        with a peak under ``below`` (default: where the bound is attained) keep it on board,
        -2 where they send it off board (or it is shared); None where a robot has none."""
        price = self.price if price is None else price
        below = self.below if below is None else below
        x = np.full(n_instances, -2, dtype=np.int64)
        for g in self.groups:
            if not g.instances.size:
                continue
            cost = np.where(g.peaks < below - EPS, g.costs[price], np.inf)
            best = np.argmin(cost, axis=1)
            if not np.isfinite(cost[np.arange(len(g.robots)), best]).all():
                return None
            on = g.configs[best]  # (R, s)
            x[g.instances[on]] = np.broadcast_to(g.robots[:, None], on.shape)[on]
        return x


def robot_bound(problem: Problem, weights: Mapping[str, float] | None = None) -> float | None:
    """A lower bound on every plan's S that knows a robot's instances are whole (module
    docstring), or None where it does not apply (``robot_dual``)."""
    dual = robot_dual(problem, weights)
    return None if dual is None else dual.bound


def robot_dual(
    problem: Problem,
    weights: Mapping[str, float] | None = None,
    fit: Fit | None = None,
    stop: Callable[[], bool] | None = None,
) -> RobotDual | None:
    """The robot bound of the module docstring with its price and threshold, or None where it
    does not apply: no robot, an instance allowed on a robot other than its home, more than
    ``MAX_ON_BOARD`` instances on a robot, an instance with no node, or weights the MILP
    cannot linearise. ``fit``: the search's own (limits allocation), to reuse its tables;
    ``stop`` (the planning budget) is asked between the steps and ends it with None."""
    halt = stop or (lambda: False)
    w = dict(DEFAULT_WEIGHTS if weights is None else weights)
    if set(w) - set(LINEAR):
        return None
    robots = np.flatnonzero(problem.tier == 0)
    home = problem.home
    on_robot = problem.allowed[:, robots]
    others = on_robot & (robots[None, :] != home[:, None])
    sizes = np.bincount(home[home >= 0], minlength=problem.n_nodes)[robots]
    if (
        not len(robots)  # a selector that matched no robot: nothing to price
        or others.any()
        or sizes.max(initial=0) > MAX_ON_BOARD
        or not problem.allowed.any(axis=1).all()
    ):
        return None
    pi, pj = np.nonzero(problem.allowed)
    c = pair_costs(problem, w, pi, pj)
    w_z, c = float(c[-1]), c[:-1]
    remote = problem.tier[pj] > 0
    cap = problem.capacity
    c_rem = float(cap[problem.tier > 0, 0].sum())
    req = problem.limits.cpu_request[pi, pj] / max(c_rem, EPS)
    lambdas = np.linspace(0.0, w_z, LAMBDA_STEPS) if w_z > 0 else np.zeros(1)
    # V[l, i]: instance i's cheapest pair at price lambdas[l] (off board, or any for a shared one)
    V = np.empty((len(lambdas), problem.n_instances))
    starts = np.searchsorted(pi, np.arange(problem.n_instances))  # pi is sorted
    # a shared replica: its cheapest pair (its share of z left out: still a bound); a robot's
    # own instance: its cheapest off-board pair
    c_off = np.where(home[pi] < 0, c, np.where(remote, c, np.inf))
    req_off = np.where(home[pi] < 0, 0.0, req)
    for k, lam in enumerate(lambdas):
        V[k] = np.minimum.reduceat(c_off + lam * req_off, starts)
    if halt():
        return None
    const = V[:, np.flatnonzero(home < 0)].sum(axis=1)  # (L,)
    cost_home = np.full(problem.n_instances, np.inf)
    at_home = (home[pi] >= 0) & (pj == home[pi])
    cost_home[pi[at_home]] = c[at_home]
    fit = Fit(problem, problem.limits) if fit is None else fit
    groups = []
    for size in np.unique(sizes):
        if halt():
            return None
        groups.append(_configurations(problem, fit, robots[sizes == size], int(size), V, cost_home))
    return _attained(tuple(groups), lambdas, const, w_z, halt)


def _configurations(
    problem: Problem, fit: Fit, group: I64, size: int, V: F64, cost_home: F64
) -> _Group:
    """Every on/off-board configuration of the robots ``group`` (each with ``size`` own
    instances): its peak and its cost at each price."""
    n_l = V.shape[0]
    if size == 0:  # robots with none of the fleet's instances: nothing to choose (u >= 0)
        return _Group(
            group,
            np.zeros((len(group), 0), dtype=np.int64),
            np.zeros((1, 0), dtype=bool),
            np.zeros((len(group), 1)),
            np.zeros((n_l, len(group), 1)),
        )
    cap = problem.capacity
    inst = np.stack([np.flatnonzero(problem.home == h) for h in group])
    configs = np.array(list(np.ndindex(*(2,) * size)), dtype=bool).reshape(-1, size)
    dem = fit.demand_at(inst.ravel(), np.repeat(group, size)).reshape(len(group), size, 3)
    load = fit.reserve[group][:, None, :] + np.einsum("ks,rsq->rkq", configs.astype(float), dem)
    traffic = (~configs).astype(float) @ problem.traffic[inst].T  # (K, R)
    capg = cap[group][:, None, :]
    ok = (load <= capg * (1 + 1e-9) + 1e-9).all(axis=2)
    ok &= UPLINK_SHARE * problem.uplink_bandwidth[group][:, None] + 1e-6 >= traffic.T
    ok &= (configs[None, :, :] <= np.isfinite(cost_home[inst])[:, None, :]).all(axis=2)
    off_ok = np.isfinite(V[0][inst])[:, None, :] | configs[None, :, :]
    ok &= off_ok.all(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        util = np.where(capg > 0, load / np.where(capg > 0, capg, 1.0), 0.0).max(axis=2)
    on_cost = np.where(
        configs, np.where(np.isfinite(cost_home[inst]), cost_home[inst], 0.0)[:, None, :], 0.0
    ).sum(axis=2)
    off = np.where(np.isfinite(V[:, inst]), V[:, inst], 0.0)  # (L, R, s)
    F = on_cost[None] + np.einsum("ks,lrs->lrk", (~configs).astype(float), off)
    return _Group(group, inst, configs, np.where(ok, util, np.inf), np.where(ok[None], F, np.inf))


def _attained(
    groups: tuple[_Group, ...], lambdas: F64, const: F64, w_z: float, halt: Callable[[], bool]
) -> RobotDual | None:
    """The bound: for each interval [a, b) of robot peaks, the best price; the least of
    those over the intervals (every plan's z lies in one of them). None where ``halt``
    says to stop."""
    U_all = np.concatenate([g.peaks.ravel() for g in groups])
    cuts = np.unique(U_all[np.isfinite(U_all)])
    t_min = max(float(np.max([g.peaks.min(axis=1).max(initial=0.0) for g in groups])), 0.0)
    cuts = cuts[cuts >= t_min - EPS]
    if len(cuts) > MAX_THRESHOLDS:
        cuts = np.quantile(cuts, np.linspace(0, 1, MAX_THRESHOLDS), method="lower")
    # per group, each robot's configurations by rising peak and the cheapest so far at each
    # price: the cheapest with u < b is then one look-up per robot, not a pass over all
    ladders = []
    for g in groups:
        order = np.argsort(g.peaks, axis=1)  # (R, K)
        by_peak = np.take_along_axis(g.costs, order[None], axis=2)
        ladders.append(
            (np.take_along_axis(g.peaks, order, axis=1), np.minimum.accumulate(by_peak, 2))
        )
    best: tuple[float, int, float] = (np.inf, 0, np.inf)
    for a, b in zip(cuts, np.append(cuts[1:], np.inf), strict=True):
        if halt():
            return None
        # every t in [a, b): configurations with u < b allowed, z >= a
        total = const.copy()
        for peaks, cheapest in ladders:
            below = (peaks < b - EPS).sum(axis=1)  # (R,) configurations allowed
            at = np.take_along_axis(cheapest, np.maximum(below - 1, 0)[None, :, None], 2)[..., 0]
            total += np.where(below > 0, at, np.inf).sum(axis=1)
        values = total + (w_z - lambdas) * a
        k = int(np.argmax(values))
        if float(values[k]) < best[0]:
            best = (float(values[k]), k, float(b))
    if not np.isfinite(best[0]):
        return None
    return RobotDual(bound=best[0], price=best[1], below=best[2], groups=groups)


def priced_plans(
    problem: Problem, fit: Fit, dual: RobotDual, stop: Callable[[], bool] | None = None
) -> list[I64]:
    """The Lagrangian heuristic of the module docstring: the configurations where the bound
    is attained, the rest packed off board. Where the packing fails (the edges cannot hold
    what the price sends them), a higher price keeps more on board (three prices tried, up to
    the reserve's weight); where a plan's robots run hotter than its edge and cloud nodes,
    the configurations are chosen again under the off-board peak. Each distinct plan found
    is returned; ``stop`` (the planning budget) is asked first and before each packing."""
    top = dual.prices - 1
    prices = sorted({dual.price, (dual.price + top) // 2, top})
    if stop is not None and stop():  # before the (I, N) tables below (~1 s at 1000 robots)
        return []
    remote = problem.allowed & ~fit.robots[None, :]
    # off board on the nodes that miss about as little as the best of them (as levelling)
    q = np.where(remote, fit.q, np.inf)
    near = remote & (q <= q.min(axis=1, initial=np.inf)[:, None] + MISS_TOLERANCE)
    # a shared instance that may run only on robots goes where it may
    allowed = np.where(remote.any(axis=1)[:, None], near, problem.allowed)
    plans: list[I64] = []
    seen: set[bytes] = set()
    for price in prices:
        below = dual.below
        for _ in range(ROUNDS):
            start = dual.on_board(problem.n_instances, price, below)
            if start is None or start.tobytes() in seen:
                break
            seen.add(start.tobytes())
            if stop is not None and stop():
                return plans
            x = pack_off_board(fit, start, np.flatnonzero(start == -2), allowed)
            if x is None:
                break
            plans.append(x)
            peaks = node_peaks(fit, x)
            off_peak = float(peaks[~fit.robots].max(initial=0.0))
            if float(peaks[fit.robots].max(initial=0.0)) <= off_peak + EPS:
                break
            below = off_peak + EPS  # robots no hotter than the edges
        if plans:
            return plans
    return plans


def with_priced(
    pp: PlacementProblem,
    X: I64,
    F: F64,
    weights: Mapping[str, float],
    stop: Callable[[], bool] | None = None,
) -> tuple[I64, F64, float | None]:
    """The archive (genes, objectives) plus the priced plans under ``weights`` that are
    feasible (nothing added without ``reserve``, or where the robot bound does not apply),
    and the robot bound under ``weights`` (None where not computed); ``stop`` (the planning
    budget) skips or ends it (the bound and the packings ask it between their steps, so a
    budget is overrun by one step at most)."""
    if "reserve" not in pp.names or (stop is not None and stop()):
        return X, F, None
    dual = robot_dual(pp.fleet, weights, pp.fit, stop)
    if dual is None:
        return X, F, None
    plans = priced_plans(pp.fleet, pp.fit, dual, stop)
    if not plans:
        return X, F, dual.bound
    genes = np.stack(plans)[:, pp.genes]
    out: dict[str, F64] = {}
    pp._evaluate(genes, out)
    ok = np.maximum(out["G"], 0.0).sum(axis=1) <= 1e-9
    return np.concatenate([X, genes[ok]]), np.concatenate([F, out["F"][ok]]), dual.bound
