"""Pareto local search (the memetic step of ``solver.nsga2``), vectorised over neighbourhoods.

NSGA-II's variation rarely finds the last few single-instance moves that lower a max-type
objective such as ``reserve``: a move only helps once it is the only instance keeping the
peak node at its peak. ``pareto_local_search`` enumerates, for every plan of an archive (the
final feasible non-dominated set), all feasible one-gene moves (each instance to each other
node of its gene space) and evaluates them in one call of the vectorised evaluation; every
neighbour that no archive member weakly dominates joins the archive (and dominated members
leave it). New members are explored in the next round, until no move improves the archive,
``rounds`` have run or the deadline passes. It is deterministic: no random draws.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from .problem import PlacementProblem

__all__ = ["dominated_by", "pareto_local_search"]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
# neighbours evaluated per call of the vectorised evaluation (bounds the memory used)
CHUNK = 4096


def dominated_by(F: F64, A: F64) -> NDArray[np.bool_]:
    """Rows of F weakly dominated by (or equal to) some row of A (minimisation)."""
    if len(A) == 0 or len(F) == 0:
        return np.zeros(len(F), dtype=bool)
    out = np.zeros(len(F), dtype=bool)
    for s in range(0, len(F), CHUNK):
        f = F[s : s + CHUNK, None, :]
        out[s : s + CHUNK] = np.all(A[None, :, :] <= f, axis=2).any(axis=1)
    return out


def _filter_front(X: I64, F: F64) -> tuple[I64, F64]:
    """The non-dominated rows of (X, F), one per distinct objective vector (first kept)."""
    keep = np.ones(len(F), dtype=bool)
    for k in range(len(F)):
        if not keep[k]:
            continue
        le = np.all(F[k][None, :] <= F, axis=1)
        lt = np.any(F[k][None, :] < F, axis=1)
        same = np.all(F[k][None, :] == F, axis=1)
        same[: k + 1] = False
        keep &= ~((le & lt) | same)
    return X[keep], F[keep]


def _neighbours(pp: PlacementProblem, x: I64, limit: int) -> I64:
    """The one-gene moves of the plan x (G genes) that keep every capacity and uplink
    constraint: (M, G). Checked incrementally from x's per-node use, so infeasible moves are
    never evaluated."""
    fleet, fit = pp.fleet, pp.fit
    genes = pp.genes
    g = np.repeat(np.arange(pp.n_var), pp.counts)
    node = pp.table[g, np.concatenate([np.arange(c) for c in pp.counts])]
    cur = x[g]
    move = node != cur
    g, node, cur = g[move], node[move], cur[move]
    inst = genes[g]
    full = pp.full(x)[0]
    valid = full >= 0
    xc = np.where(valid, full, 0)
    n = fleet.n_nodes
    used = np.zeros((n, 3))
    for r in range(3):
        w = np.where(valid, fit.demand[np.arange(fleet.n_instances), xc, r], 0.0)
        used[:, r] = np.bincount(xc, weights=w, minlength=n)
    ok = np.all(used[node] + fit.demand[inst, node] <= fit.cap[node] + 1e-9, axis=1)
    home = fleet.home[inst]
    h = np.where(home >= 0, home, 0)
    off_i = valid & (fleet.home >= 0) & (xc != fleet.home)
    up = np.bincount(
        np.where(fleet.home >= 0, fleet.home, 0),
        weights=np.where(off_i, fleet.traffic, 0.0),
        minlength=n,
    )
    delta = fleet.traffic[inst] * ((node != h).astype(float) - (cur != h).astype(float))
    ok &= (home < 0) | (delta <= 0) | (up[h] + delta <= fit.uplink[h] + 1e-9)
    g, node = g[ok][:limit], node[ok][:limit]
    out = np.repeat(x[None, :], len(g), axis=0)
    out[np.arange(len(g)), g] = node
    return out


def _evaluate(pp: PlacementProblem, X: I64) -> tuple[F64, NDArray[np.bool_]]:
    """Quantised objectives and feasibility of the plans X (genes)."""
    out: dict[str, F64] = {}
    pp._evaluate(X, out)
    G = out.get("G")
    feasible = (
        np.all(G <= 1e-9, axis=1) if G is not None and G.size else np.ones(len(X), dtype=bool)
    )
    return np.asarray(out["F"], dtype=np.float64), feasible


def pareto_local_search(
    pp: PlacementProblem,
    X: I64,
    F: F64,
    *,
    rounds: int = 10,
    max_cells: int = 4_000_000,
    deadline: float = float("inf"),
) -> tuple[I64, F64, int]:
    """Improve the archive (X genes, F quantised objectives; feasible plans) by one-gene moves.

    At most ``max_cells`` (plans evaluated x instances) of work, so the step costs about the
    same as the NSGA-II run on the warehouse fleet and stays a small share on large fleets;
    the result depends only on the inputs unless ``deadline`` (a ``time.perf_counter``
    value, checked between evaluation chunks) cuts it short.
    Returns the new archive (non-dominated, feasible) and the number of plans evaluated.
    """
    max_evals = max(max_cells // max(pp.fleet.n_instances, 1), 1)
    X, F = _filter_front(np.asarray(X, dtype=np.int64), np.asarray(F, dtype=np.float64))
    todo = np.ones(len(X), dtype=bool)
    n_eval = 0
    for _ in range(rounds):
        if not todo.any() or time.perf_counter() > deadline:
            break
        left = max_evals - n_eval
        parts: list[I64] = []
        for x in X[todo]:
            if left <= 0:
                break
            parts.append(_neighbours(pp, x, left))
            left -= len(parts[-1])
        cand = np.unique(np.concatenate(parts), axis=0) if parts else X[:0]
        if len(cand) == 0:
            break
        newX: list[I64] = []
        newF: list[F64] = []
        for s in range(0, len(cand), CHUNK):
            if time.perf_counter() > deadline:
                break
            c = cand[s : s + CHUNK]
            f, ok = _evaluate(pp, c)
            n_eval += len(c)
            good = ok & ~dominated_by(f, F)
            if good.any():
                newX.append(c[good])
                newF.append(f[good])
        if not newX:
            break
        nX, nF = _filter_front(np.concatenate(newX), np.concatenate(newF))
        # archive members dominated by a newcomer leave
        stay = ~_strictly_dominated(F, nF)
        X = np.concatenate([X[stay], nX])
        F = np.concatenate([F[stay], nF])
        todo = np.concatenate([np.zeros(int(stay.sum()), dtype=bool), np.ones(len(nX), dtype=bool)])
    return X, F, n_eval


def _strictly_dominated(F: F64, A: F64) -> NDArray[np.bool_]:
    """Rows of F that some row of A dominates (<= everywhere, < somewhere)."""
    if len(A) == 0:
        return np.zeros(len(F), dtype=bool)
    le = np.all(A[None, :, :] <= F[:, None, :], axis=2)
    lt = np.any(A[None, :, :] < F[:, None, :], axis=2)
    return np.asarray((le & lt).any(axis=1), dtype=bool)
