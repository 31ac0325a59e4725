"""Exact MILP of a scalarised objective (scipy.optimize.milp / HiGHS) for small fleets.

With the ``limits`` allocation a feasible plan never oversubscribes a CPU (requests = use),
so kappa = 1 and every instance's miss probability q_ij and missed-cycle term
activation_i * tau_>1(i, j) are constants of the pair (i, j); F1 is a sum of pair constants
too. The scalar minimised is

    S = w_missRate * missRate + w_missedCycles * missedCycles
        + w_onboard * onboard / N_R + w_reserve * reserve [+ w_cost * cost]

(defaults ``DEFAULT_WEIGHTS``: missRate is a fraction, so its weight makes 0.1 percentage
point worth 0.1; F1 is divided by the number of robots so it is a mean per robot; reserve is
linearised with an auxiliary variable z >= u_j^r / L_j^r for all nodes and resources; cost,
the requested cores times each node's price, is linear as it is). F3 (balance, a standard
deviation) is quadratic and left out. ``scalarised`` computes the same S for any plan, so a
heuristic's gap to the optimum can be reported. The ``exact`` scheduler of a fleet adds cost
(``fleet_weights``): at the fleet's weight when it lists or weighs cost, else as a small
tie-break on a site with priced nodes, as the lexicographic choice takes the cheapest of the
plans that miss alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.objectives import ObjectiveName
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible, InvalidSpec

from .heuristics import uncontended_miss
from .objectives import UPLINK_SHARE, evaluate

if TYPE_CHECKING:
    import scipy.sparse as sp
    from scipy.optimize import LinearConstraint

# scipy (0.4 s to import) is imported where the solver runs: `kubectl fogfleet top` and the
# other commands that only read a plan reach this module through fogfleet.scheduling

__all__ = [
    "COST_TIE_BREAK",
    "DEFAULT_WEIGHTS",
    "MAX_PAIRS",
    "ExactResult",
    "describe_weights",
    "fleet_weights",
    "lp_bound",
    "pair_costs",
    "scalarised",
    "scalarised_plans",
    "solve_exact",
]

DEFAULT_WEIGHTS: dict[str, float] = {
    ObjectiveName.MISS_RATE.value: 100.0,
    ObjectiveName.MISSED_CYCLES.value: 1.0,
    ObjectiveName.ONBOARD.value: 1.0,
    ObjectiveName.RESERVE.value: 1.0,
}
# cost's weight when the fleet names no cost but pays for some nodes: small beside the
# defaults (0.1 core-hour price unit = 1e-4 of S), so it only breaks near-ties, as the
# lexicographic choice's cost tie-break does
COST_TIE_BREAK = 1e-3
LINEAR = (*DEFAULT_WEIGHTS, ObjectiveName.COST.value)  # what the MILP can weigh
F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
MAX_PAIRS = 5000  # binary variables the exact solver accepts (the warehouse fleet has ~250)


@dataclass(frozen=True)
class ExactResult:
    placement: NDArray[np.int64]  # (I,), -1 for instances with an empty gene space
    value: float  # the optimal S (or the LP bound when relaxed)
    bound: float  # HiGHS' dual bound
    status: str
    relaxed: bool


def fleet_weights(
    problem: Problem, objectives: Sequence[str], weights: Mapping[str, float]
) -> dict[str, float]:
    """The weights the ``exact`` scheduler minimises for a fleet: ``DEFAULT_WEIGHTS`` plus
    cost, at the fleet's weight for it (1 unless given) when ``spec.scheduler.objectives``
    lists cost or ``weights`` names it, else at ``COST_TIE_BREAK`` when some node has a
    price (a weight of 0 leaves cost out)."""
    w = dict(DEFAULT_WEIGHTS)
    cost = ObjectiveName.COST.value
    if cost in weights or cost in objectives:
        w[cost] = float(weights.get(cost, 1.0))
    elif problem.cost.any():
        w[cost] = COST_TIE_BREAK
    return {k: v for k, v in w.items() if v > 0}


def describe_weights(weights: Mapping[str, float]) -> str:
    """``100*missRate + 1*missedCycles + ...``: the weighted sum, for people."""
    return " + ".join(f"{v:g}*{k}" for k, v in weights.items())


def scalarised(
    problem: Problem, placement: NDArray[np.integer], weights: Mapping[str, float] | None = None
) -> float:
    """S of the module docstring for one plan (limits allocation)."""
    return float(scalarised_plans(problem, np.asarray(placement)[None, :], weights)[0])


def scalarised_plans(
    problem: Problem, plans: NDArray[np.integer], weights: Mapping[str, float] | None = None
) -> F64:
    """S of each plan of ``plans`` (P, I), evaluated together (limits allocation)."""
    w = dict(DEFAULT_WEIGHTS if weights is None else weights)
    vals = evaluate(problem, np.asarray(plans), problem.limits, tuple(w))
    n_r = max(int((problem.tier == 0).sum()), 1)
    total = np.zeros(len(plans))
    for name, wk in w.items():
        v = np.asarray(vals[name], dtype=np.float64)
        total += wk * (v / n_r if name == ObjectiveName.ONBOARD.value else v)
    return total


def solve_exact(
    problem: Problem,
    weights: Mapping[str, float] | None = None,
    *,
    max_pairs: int = MAX_PAIRS,
    relax: bool = False,
    time_limit: float = 60.0,
) -> ExactResult:
    """Minimise S over all feasible plans. ``relax`` solves the LP relaxation instead (a lower
    bound on S at any size). Raises InvalidSpec above ``max_pairs`` binaries and Infeasible
    when no plan satisfies the constraints."""
    w = dict(DEFAULT_WEIGHTS if weights is None else weights)
    unknown = set(w) - set(LINEAR)
    if unknown:
        raise InvalidSpec(
            f"RobotFleet/{problem.fleet}",
            "spec.scheduler.weights",
            f"the exact solver cannot linearise {', '.join(sorted(unknown))}",
        )
    pi, pj = np.nonzero(problem.allowed)  # the binaries: one per allowed (instance, node)
    n_pairs = len(pi)
    if n_pairs > max_pairs and not relax:
        raise InvalidSpec(
            f"RobotFleet/{problem.fleet}",
            "spec.scheduler.algorithm",
            f"exact planning is limited to {max_pairs} (instance, node) pairs; "
            f"this fleet has {n_pairs}",
        )
    from scipy.optimize import Bounds, milp

    nv = n_pairs + 1  # and z, the peak utilisation (reserve)
    res = milp(
        pair_costs(problem, w, pi, pj),
        constraints=_constraints(problem, pi, pj),
        integrality=np.append(np.zeros(n_pairs) if relax else np.ones(n_pairs), 0),
        bounds=Bounds(np.zeros(nv), np.append(np.ones(n_pairs), np.inf)),
        options={"time_limit": time_limit, "mip_rel_gap": 1e-6, "disp": False},
    )
    if res.x is None:
        raise Infeasible(
            f"RobotFleet/{problem.fleet}",
            "spec",
            f"the exact solver found no feasible plan ({res.message})",
        )
    xv = np.asarray(res.x[:n_pairs])
    placement = np.full(problem.n_instances, -1, dtype=np.int64)
    if not relax:
        chosen = xv > 0.5
        placement[pi[chosen]] = pj[chosen]
    bound = float(getattr(res, "mip_dual_bound", res.fun) if not relax else res.fun)
    return ExactResult(placement, float(res.fun), bound, str(res.message), relax)


def lp_bound(
    problem: Problem, weights: Mapping[str, float] | None = None, *, time_limit: float = 3600.0
) -> float:
    """The LP relaxation's optimum of S (a lower bound on every plan's S) by HiGHS' interior
    point method: at 1000 robots x 8 modules (2.4 M pairs) ``solve_exact(relax=True)``'s
    simplex did not finish in 60 s, the interior point method took ~3 CPU minutes. Raises
    Infeasible when it finds no optimum."""
    import scipy.sparse as sp
    from scipy.optimize import linprog

    w = dict(DEFAULT_WEIGHTS if weights is None else weights)
    pi, pj = np.nonzero(problem.allowed)
    lc = _constraints(problem, pi, pj)
    A = sp.csr_matrix(lc.A)
    lb, ub = np.asarray(lc.lb, dtype=np.float64), np.asarray(lc.ub, dtype=np.float64)
    eq = lb == ub
    res = linprog(
        pair_costs(problem, w, pi, pj),
        A_ub=A[~eq],
        b_ub=ub[~eq],
        A_eq=A[eq],
        b_eq=ub[eq],
        bounds=(0, None),  # the assignment rows keep every pair's share <= 1
        method="highs-ipm",
        options={"time_limit": time_limit, "disp": False},
    )
    if res.status != 0:
        raise Infeasible(f"RobotFleet/{problem.fleet}", "spec", f"no LP bound ({res.message})")
    return float(res.fun)


def pair_costs(problem: Problem, w: Mapping[str, float], pi: I64, pj: I64) -> F64:
    """The cost of each pair's binary in S, then z's (the reserve weight); also the
    configurations' costs of ``configurations.robot_dual``."""
    alloc = problem.limits
    n_r = max(int((problem.tier == 0).sum()), 1)
    genes = np.flatnonzero(problem.allowed.any(axis=1))
    a = problem.activation
    # missRate is the mean over modules of each module's activation-weighted share
    # (Evaluation.miss_rate); every instance with a gene space is placed, so each pair's
    # weight a_i / (W_module(i) * modules) is a constant
    mod = problem.module_index
    w_mod = np.bincount(mod[genes], weights=a[genes], minlength=len(problem.module_names))
    n_mod = max(int((w_mod > 0).sum()), 1)
    share = a / np.where(w_mod[mod] > 0, w_mod[mod] * n_mod, 1.0)
    # at the allowed pairs only: the (I, N) tables would be 11 M cells at 1000 robots, where
    # 2.4 M pairs are allowed
    q = uncontended_miss(problem, alloc, pi, pj)
    tau = (problem.net_mean[pi, pj] + alloc.exe_mean[pi, pj]) / problem.cycle[pi]
    cap = problem.capacity
    on_home = pj == problem.home[pi]
    # F1 as ``Evaluation.cpu_onboard`` / ``mem_requested`` count it: at home, a fallback's
    # share is in its robot's reserve (a constant), so only the rest counts
    held = problem.held_at_home[pi] & on_home
    fb = problem.fallback_share(alloc)[pi]
    use = a[pi] * alloc.cpu_use[pi, pj]
    use = np.where(held, np.maximum(use - fb[:, 0], 0.0), use)
    mem = np.where(held, problem.memory[pi] - fb[:, 1], problem.memory[pi])
    f1 = np.where(on_home, use / cap[pj, 0] + mem / np.maximum(cap[pj, 1], 1.0), 0.0)
    # cost: the cores requested on the node times its price (``Evaluation.cost``; the
    # reserve's part is a constant)
    cores = np.where(held, alloc.cpu_request[pi, pj] - fb[:, 0], alloc.cpu_request[pi, pj])
    c = (
        w.get(ObjectiveName.MISS_RATE.value, 0.0) * share[pi] * q
        + w.get(ObjectiveName.MISSED_CYCLES.value, 0.0) * a[pi] * np.where(tau > 1.0, tau, 0.0)
        + w.get(ObjectiveName.ONBOARD.value, 0.0) * f1 / n_r
        + w.get(ObjectiveName.COST.value, 0.0) * problem.cost[pj] * cores
    )
    return np.append(c, w.get(ObjectiveName.RESERVE.value, 0.0))  # z


def _constraints(problem: Problem, pi: I64, pj: I64) -> LinearConstraint:
    """Each placeable instance on exactly one node; every node within its capacity, and z at
    least its utilisation; every robot's off-board traffic within its uplink share."""
    import scipy.sparse as sp
    from scipy.optimize import LinearConstraint

    n_pairs = len(pi)
    nv = n_pairs + 1
    cols = np.arange(n_pairs)
    genes = np.flatnonzero(problem.allowed.any(axis=1))
    pos = np.searchsorted(genes, pi)
    rows: list[sp.csr_matrix] = [
        sp.csr_matrix((np.ones(n_pairs), (pos, cols)), shape=(len(genes), nv))
    ]
    lo: list[F64] = [np.ones(len(genes))]
    hi: list[F64] = [np.ones(len(genes))]
    for block in (_capacity_rows(problem, pi, pj), _uplink_rows(problem, pi, pj)):
        for m, low, high in block:
            rows.append(m)
            lo.append(low)
            hi.append(high)
    A = sp.vstack(rows, format="csr")
    return LinearConstraint(A, np.concatenate(lo), np.concatenate(hi))


_Rows = list[tuple["sp.csr_matrix", F64, F64]]  # (matrix, lower bounds, upper bounds)


def _capacity_rows(problem: Problem, pi: I64, pj: I64) -> _Rows:
    """Per resource: each node's requests within its capacity, and (the reserve) z at least
    each node's utilisation u_j^r / L_j^r."""
    import scipy.sparse as sp

    alloc = problem.limits
    n_n, n_pairs = problem.n_nodes, len(pi)
    nv, cols, cap = n_pairs + 1, np.arange(n_pairs), problem.capacity
    demand = [alloc.cpu_request[pi, pj], problem.memory[pi], problem.gpu[pi]]
    # a fallback's share at home is its robot's reserve, held whatever the plan (a constant);
    # on board the instance adds only the rest
    held = problem.held_at_home[pi] & (pj == problem.home[pi])
    share = problem.fallback_share(alloc)[pi]
    demand = [np.where(held, d - share[:, r], d) for r, d in enumerate(demand)]
    reserve = problem.fallback_reserve(alloc)
    z = sp.csr_matrix((-np.ones(n_n), (np.arange(n_n), np.full(n_n, n_pairs))), shape=(n_n, nv))
    out: _Rows = []
    for r in range(3):
        # rows in units of the node's capacity (memory in bytes would span 1e9 and make
        # HiGHS numerically fragile: it has reported this feasible model as infeasible)
        has = cap[:, r] > 0
        scale = np.where(has, 1.0 / np.where(has, cap[:, r], 1.0), 1.0)
        m = sp.csr_matrix((demand[r] * scale[pj], (pj, cols)), shape=(n_n, nv))
        m.eliminate_zeros()
        held_r = reserve[:, r] * scale
        out.append((m, np.full(n_n, -np.inf), np.where(has, 1.0, 0.0) - held_r))
        if r < 2 or has.any():
            # reserve: u_j^r / L_j^r - z <= 0
            mr = (m + z)[np.flatnonzero(has)]
            out.append(
                (sp.csr_matrix(mr), np.full(mr.shape[0], -np.inf), -held_r[np.flatnonzero(has)])
            )
    return out


def _uplink_rows(problem: Problem, pi: I64, pj: I64) -> _Rows:
    """Each robot's off-board traffic within ``UPLINK_SHARE`` of its uplink."""
    import scipy.sparse as sp

    n_pairs = len(pi)
    cols = np.arange(n_pairs)
    robots = np.flatnonzero(problem.tier == 0)
    off = (problem.home[pi] >= 0) & (pj != problem.home[pi])
    ridx = np.searchsorted(robots, problem.home[pi])
    limit = UPLINK_SHARE * problem.uplink_bandwidth[robots]
    mu = sp.csr_matrix(
        (problem.traffic[pi][off] / limit[ridx[off]], (ridx[off], cols[off])),
        shape=(len(robots), n_pairs + 1),
    )
    return [(mu, np.full(len(robots), -np.inf), np.ones(len(robots)))]
