"""Shared services survive a node (issue 35 item 3): the replicas of a shared module go to at
least two nodes whenever two of their allowed nodes exist.

A repair, not a constraint: every plan the search makes passes through it (``CapacityRepair``,
and the greedy plans it is seeded with), so a plan with a shared module stacked on one node is
only left when no second allowed node has room for one of its replicas. The move is of one
replica, to the allowed node with room where it misses least (``Fit.pref``), so the plan pays
as little as it can for it; what it pays shows in the plan's objectives, and ``spread_note``
says in the choice reason which modules were spread.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem

from .heuristics import Fit

__all__ = ["spread_groups", "spread_note", "spread_plans", "stacked", "stacks_more"]

I64 = NDArray[np.int64]
_EPS = 1e-9


def spread_groups(problem: Problem) -> list[I64]:
    """The instances of each shared module with two or more replicas whose allowed nodes
    together number two or more (the modules the rule binds), by module name."""
    by_module: dict[str, list[int]] = {}
    for i in np.flatnonzero(problem.home < 0):  # shared replicas have no home robot
        inst = problem.instances[int(i)]
        if not inst.robot:
            by_module.setdefault(inst.module, []).append(int(i))
    out = []
    for module in sorted(by_module):
        rows = np.asarray(by_module[module], dtype=np.int64)
        if len(rows) >= 2 and int(problem.allowed[rows].any(axis=0).sum()) >= 2:
            out.append(rows)
    return out


def stacked(problem: Problem, X: NDArray[np.integer]) -> NDArray[np.bool_]:
    """(P, G) plan p has every placed replica of group g (two or more placed) on one node."""
    groups = spread_groups(problem)
    out = np.zeros((X.shape[0], len(groups)), dtype=bool)
    for g, rows in enumerate(groups):
        cols = X[:, rows]
        placed = cols >= 0
        first = np.where(placed, cols, -1).max(axis=1)  # some placed node of the plan
        same = np.all(~placed | (cols == first[:, None]), axis=1)
        out[:, g] = same & (placed.sum(axis=1) >= 2)
    return out


def stacks_more(problem: Problem, trial: NDArray[np.integer], x: NDArray[np.integer]) -> bool:
    """Plan ``trial`` has more shared modules stacked on one node than plan ``x``."""
    both = stacked(problem, np.stack([np.asarray(trial), np.asarray(x)]))
    return bool(both[0].sum() > both[1].sum())


def spread_plans(problem: Problem, x: I64, fit: Fit) -> I64:
    """Move one replica of every stacked shared module to another allowed node with room for
    it (the one where it misses least). ``x`` is (P, I), modified in place; a module whose
    other allowed nodes are all full stays where it is."""
    groups = spread_groups(problem)
    if not groups:
        return x
    bad = stacked(problem, x)
    for p in np.flatnonzero(bad.any(axis=1)):
        valid = x[p] >= 0
        rows_all = np.flatnonzero(valid)
        used = fit.reserve.copy()
        np.add.at(used, x[p, rows_all], fit.demand_at(rows_all, x[p, rows_all]))
        for g in np.flatnonzero(bad[p]):
            rows = groups[g]
            i = int(rows[x[p, rows] >= 0][-1])
            j0 = int(x[p, i])
            d = fit.demand_rows(np.array([i]))[0]  # (N, 3)
            room = problem.allowed[i] & np.all(used + d <= fit.cap + _EPS, axis=1)
            room[j0] = False
            if not room.any():
                continue
            j = int(np.argmin(np.where(room, fit.pref_rows(np.array([i]))[0], np.inf)))
            used[j0] -= d[j0]
            used[j] += d[j]
            x[p, i] = j
    return x


def spread_note(problem: Problem, x: NDArray[np.integer]) -> str:
    """What the rule did to plan ``x``, for its choice reason ("" when it binds nothing)."""
    groups = spread_groups(problem)
    if not groups:
        return ""
    left = stacked(problem, np.asarray(x)[None, :])[0]
    names = [problem.instances[int(rows[0])].module for rows in groups]
    spread = [n for n, s in zip(names, left, strict=True) if not s]
    stuck = [n for n, s in zip(names, left, strict=True) if s]
    parts = []
    if spread:
        parts.append(f"shared replicas spread over 2+ nodes: {', '.join(spread)}")
    if stuck:
        parts.append(f"no second allowed node with room for: {', '.join(stuck)}")
    return "; ".join(parts)
