"""Room for instances that fit nowhere around the others, by moving the fewest of them.

An incremental re-plan places what a change affected around what runs (``stickiness
.fill_around``). On a fleet whose nodes are full an affected instance may find no node with
room; the whole-fleet plan then used instead moved 18-20 of the warehouse's 40 instances where
2 had to leave a node (the leader-failover fault, issue 46), and the fewest moves that make
room there are 4.

``fewest_moves`` solves that exactly, as a small MILP (scipy.optimize.milp, HiGHS), over the
*candidates*: the instances to place, each on one of the ``NODES_TRIED`` allowed nodes it
prefers, and the movable instances running on those nodes, each where it runs or on one of
the ``NODES_TRIED`` nodes it prefers. Everything else stays where it is and only its load
counts. Constraints: every candidate on one node; each node's CPU requests, memory and GPUs
within its capacity (less what its robot holds for fallbacks: ``Fit.reserve``), each robot's
off-board traffic within its uplink share (``Fit.uplink``); the objective counts the moved
candidates, and by a weight below one move prefers nodes with lower miss probability (the
order ``fill_around`` places in). Its size is bounded by the candidates, not by the fleet.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem

from .heuristics import Fit
from .stickiness import loads

__all__ = ["MILP_SECONDS", "NODES_TRIED", "fewest_moves"]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
NODES_TRIED = 8  # the nodes a candidate may go to, its most preferred allowed ones
MILP_SECONDS = 5.0  # HiGHS' time limit: without an answer the caller plans in full
TIE_WEIGHT = 0.5  # all preference terms together weigh less than one move


def fewest_moves(
    problem: Problem,
    x: I64,
    todo: NDArray[np.bool_],
    fit: Fit,
    movable: NDArray[np.bool_],
    time_limit: float = MILP_SECONDS,
    nodes_tried: int = NODES_TRIED,
) -> I64 | None:
    """``x`` with the ``todo`` instances (-1 in ``x``) placed and the fewest ``movable``
    instances moved to make room (module docstring); None when the candidates cannot make it
    (or HiGHS finds nothing within ``time_limit``). ``nodes_tried`` at the number of nodes
    leaves no allowed node out: the fewest moves over every node (for a small fleet)."""
    from scipy.optimize import Bounds, LinearConstraint, milp

    place = np.flatnonzero(todo)
    pref = fit.pref_rows(place)
    nodes = sorted({j for k in range(len(place)) for j in _preferred(pref[k], nodes_tried)})
    moving = np.flatnonzero(movable & ~todo & np.isin(x, nodes))
    cand = np.concatenate([place, moving]).astype(np.int64)
    prefs = np.vstack([pref, fit.pref_rows(moving)]) if moving.size else pref
    pairs = [
        (k, j)
        for k, i in enumerate(cand)
        for j in sorted(
            set(_preferred(prefs[k], nodes_tried)) | ({int(x[i])} if x[i] >= 0 else set())
        )
    ]
    if not pairs:
        return None
    rest = x.copy()
    rest[cand] = -1
    used, up = loads(problem, rest)
    kk = np.array([k for k, _ in pairs], dtype=np.int64)
    jj = np.array([j for _, j in pairs], dtype=np.int64)
    ii = cand[kk]
    cost = ((x[ii] >= 0) & (jj != x[ii])).astype(np.float64)
    finite = np.where(np.isfinite(prefs[kk, jj]), prefs[kk, jj], 0.0)
    cost += TIE_WEIGHT * finite / max(float(finite.sum()), 1e-12)
    rows = [_one_node_each(kk, len(cand))]
    bounds = [(np.ones(len(cand)), np.ones(len(cand)))]
    cap_rows, cap_ub = _capacities(fit, ii, jj, used)
    rows.append(cap_rows)
    bounds.append((np.full(cap_ub.size, -np.inf), cap_ub))
    up_rows, up_ub = _uplinks(problem, fit, ii, jj, up)
    if up_ub.size:
        rows.append(up_rows)
        bounds.append((np.full(up_ub.size, -np.inf), up_ub))
    import scipy.sparse as sp

    res = milp(
        cost,
        constraints=LinearConstraint(
            sp.vstack(rows).tocsr(),
            np.concatenate([b[0] for b in bounds]),
            np.concatenate([b[1] for b in bounds]),
        ),
        integrality=np.ones(len(pairs)),
        bounds=Bounds(0, 1),
        options={"time_limit": time_limit, "disp": False},
    )
    if res.x is None:
        return None
    out = rest
    chosen = np.flatnonzero(res.x > 0.5)
    out[ii[chosen]] = jj[chosen]
    return out if bool((out[cand] >= 0).all()) else None


def _preferred(pref: F64, count: int) -> list[int]:
    """The ``count`` allowed nodes (finite ``pref``) preferred most."""
    order = np.argsort(pref, kind="stable")[:count]
    return [int(j) for j in order if np.isfinite(pref[j])]


def _one_node_each(kk: I64, n: int) -> Any:
    """Rows: each candidate's pairs sum to one."""
    import scipy.sparse as sp

    return sp.csr_matrix((np.ones(kk.size), (kk, np.arange(kk.size))), shape=(n, kk.size))


def _capacities(fit: Fit, ii: I64, jj: I64, used: F64) -> tuple[Any, F64]:
    """Rows: per node and resource the candidates' demand within what the rest leaves, in
    units of the node's capacity (as ``exact._capacity_rows``: memory in bytes would span 1e9
    and make HiGHS numerically fragile)."""
    import scipy.sparse as sp

    nodes = np.unique(jj)
    cap = fit.cap[nodes]
    scale = np.where(cap > 0, 1.0 / np.where(cap > 0, cap, 1.0), 1.0)  # (nodes, 3)
    demand = fit.demand_at(ii, jj)  # (P, 3)
    row_of = {int(j): r for r, j in enumerate(nodes)}
    r = np.array([row_of[int(j)] for j in jj], dtype=np.int64)
    rows, cols, vals = [], [], []
    for res in range(3):
        rows.append(r * 3 + res)
        cols.append(np.arange(jj.size))
        vals.append(demand[:, res] * scale[r, res])
    m = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(nodes.size * 3, jj.size),
    )
    ub: F64 = ((cap - used[nodes]) * scale).reshape(-1)
    return m, ub


def _uplinks(problem: Problem, fit: Fit, ii: I64, jj: I64, up: F64) -> tuple[Any, F64]:
    """Rows: per robot the candidates' off-board traffic within what the rest leaves, in units
    of its uplink share (bits per second would span 1e8)."""
    import scipy.sparse as sp

    home = problem.home[ii]
    away = (home >= 0) & (jj != home)
    robots = np.unique(home[away])
    if robots.size == 0:
        return None, np.zeros(0)
    row_of = {int(h): r for r, h in enumerate(robots)}
    cols = np.flatnonzero(away)
    r = np.array([row_of[int(h)] for h in home[cols]], dtype=np.int64)
    share = np.maximum(fit.uplink[robots], 1e-12)
    m = sp.csr_matrix(
        (problem.traffic[ii[cols]] / share[r], (r, cols)), shape=(robots.size, jj.size)
    )
    ub: F64 = (fit.uplink[robots] - up[robots]) / share
    return m, ub
