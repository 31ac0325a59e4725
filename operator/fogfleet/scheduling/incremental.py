"""Incremental re-planning: a change that touches few instances re-plans only those, plus a
small neighbourhood, from the current placement.

A robot joining or leaving, one node failing or one module changing leaves most of a good
plan good; planning the whole fleet again (``solver.nsga2``) costs seconds per hundred robots
and proposes moves the migration-margin rule then has to argue away. ``replan``:

1. *Affected* instances: those without a usable current node (new, or their node is gone or
   no longer allowed), those a node that shrank or a module that grew no longer fits (released
   as ``stickiness`` releases overloads), and those whose own inputs changed
   (``changed_instances``).
2. Beyond ``MAX_AFFECTED_SHARE`` of the placeable instances the change is not local: the
   caller plans the fleet in full.
3. A *neighbourhood* of at most ``NEIGHBOURHOOD_SHARE`` of the other instances is freed too:
   those whose current node is furthest from their best one (their uncontended miss
   probability, ``heuristics.uncontended_miss``, above their best allowed node's), then those
   on the same robot as an affected instance (they share its CPU and uplink), then those on
   the fullest nodes the affected instances may use (moving them makes room).
4. Every other instance is fixed on its node (its gene space narrowed to it). The free ones
   start where they run if it still fits, else on the node they prefer with room
   (``stickiness`` fill); where the affected fit nowhere around the others, the fewest moves
   of running instances that make room for them (``room.fewest_moves``, an exact MILP over
   the nodes they prefer) give the start, and what they moved is free too. They may go to
   their current node or any of their ``CANDIDATE_NODES`` most preferred nodes with room; a
   Pareto local search (``local.pareto_local_search``, bounded by ``MAX_MOVES`` scored moves,
   and by ``MAX_MOVE_CELLS`` moves x nodes on a large cluster: a move costs a pass over the
   nodes) improves that start and the fleet's choice rule picks from what it found, as
   ``solver.nsga2`` does.
5. The result is *accepted* when it is feasible and its first objective is no worse than the
   ``reference`` (the deployed plan's value) by more than the migration margin (relative) or
   ``stickiness.ABS_TOLERANCE`` (absolute); otherwise the caller plans the fleet in full.

So the plan moves at most the affected instances, the neighbourhood and what made room: a
robot joining at 1000 robots frees its 8 instances and 80 neighbours out of 8000.
"""

from __future__ import annotations

import math
import time
from collections.abc import Collection
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem, freeze

from .baselines import finish
from .choice import non_dominated
from .heuristics import Fit, best_uncontended_miss, uncontended_miss
from .local import pareto_local_search
from .preference import polish
from .problem import PlacementProblem
from .room import fewest_moves
from .schedule import Schedule
from .solver import choose_plan
from .spread import stacked
from .stickiness import ABS_TOLERANCE, fill_around, loads, still_fitting, usable_current

__all__ = [
    "CANDIDATE_NODES",
    "MAX_AFFECTED_SHARE",
    "MAX_MOVES",
    "MAX_MOVE_CELLS",
    "NEIGHBOURHOOD_SHARE",
    "Replan",
    "changed_instances",
    "replan",
]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
B = NDArray[np.bool_]

MAX_AFFECTED_SHARE = 0.1  # more affected instances than this share: not local, plan in full
NEIGHBOURHOOD_SHARE = 0.01  # of the unaffected instances, freed around the affected ones
CANDIDATE_NODES = 8  # nodes a free instance may try besides its current one
MAX_MOVES = 4_000  # single-instance moves the local search scores at most
# ... and at most this many moves x nodes: 4000 moves up to 750 nodes, 2141 at 1000 robots
# (1401 nodes: the re-plan 0.37 s instead of 0.50 s, median of 7 with one BLAS thread; the
# same plan after a robot joins, within 0.02 % on every objective after an edge fails)
MAX_MOVE_CELLS = 3_000_000
# changed_instances compares views block by block up to this many blocks, else gathers copies
MAX_COMPARED_BLOCKS = 4_096
# miss probabilities closer than this count as equal when ranking the neighbourhood
REGRET_RESOLUTION = 1e-6


@dataclass(frozen=True)
class Replan:
    """An incremental re-plan's outcome: ``schedule`` None means "plan the fleet in full"
    and ``reason`` says why; otherwise ``reason`` says what was freed and what moved."""

    schedule: Schedule | None
    affected: int
    freed: int
    reason: str


def changed_instances(old: Problem, new: Problem) -> set[int]:
    """Instances of ``new`` (by robot, module and replica) whose own planning inputs differ
    from ``old``'s: activation, cycle, memory, GPU, traffic, or, on a node both problems
    know and allow it on, its CPU request, execution or network time. A narrower gene space
    is not a change here (an instance whose node it lost has no usable current node, which
    affects it anyway), nor is a wider one (the neighbourhood may use it); new instances are
    affected by having no current node.

    The (instances x nodes) arrays are compared block by block over the runs of rows and
    columns both problems hold in the same order (``_runs``: a robot joining splits the rows
    into one run per module and the columns into two), as views: gathering them whole with
    fancy indexing copied ten arrays of 8000 x 1400 at 1000 robots (about 1 s)."""
    where = {inst: k for k, inst in enumerate(old.instances)}
    pairs = [(i, where[inst]) for i, inst in enumerate(new.instances) if inst in where]
    if not pairs:
        return set()
    ni = np.array([p[0] for p in pairs], dtype=np.int64)
    oi = np.array([p[1] for p in pairs], dtype=np.int64)
    cols = {n.name: j for j, n in enumerate(old.nodes)}
    common = [(j, cols[n.name]) for j, n in enumerate(new.nodes) if n.name in cols]
    nj = np.array([c[0] for c in common], dtype=np.int64)
    oj = np.array([c[1] for c in common], dtype=np.int64)
    diff = np.zeros(len(ni), dtype=bool)
    for name in ("activation", "cycle", "memory", "gpu", "traffic"):
        diff |= getattr(new, name)[ni] != getattr(old, name)[oi]
    pairs_2d = [
        (new.limits.cpu_request, old.limits.cpu_request),
        (new.limits.exe_mean, old.limits.exe_mean),
        (new.limits.exe_std, old.limits.exe_std),
        (new.net_mean, old.net_mean),
        (new.net_std, old.net_std),
    ]
    row_runs, col_runs = _runs(ni, oi), _runs(nj, oj)
    if len(row_runs) * len(col_runs) > MAX_COMPARED_BLOCKS:
        at_new, at_old = np.ix_(ni, nj), np.ix_(oi, oj)
        both = new.allowed[at_new] & old.allowed[at_old]
        for new_arr, old_arr in pairs_2d:
            diff |= np.any(both & (new_arr[at_new] != old_arr[at_old]), axis=1)
        return {int(i) for i in ni[diff]}
    for at, rn, ro, rows in row_runs:
        for _, cn, co, width in col_runs:
            block_new = (slice(rn, rn + rows), slice(cn, cn + width))
            block_old = (slice(ro, ro + rows), slice(co, co + width))
            both = new.allowed[block_new] & old.allowed[block_old]
            for new_arr, old_arr in pairs_2d:
                differs = both & (new_arr[block_new] != old_arr[block_old])
                diff[at : at + rows] |= np.any(differs, axis=1)
    return {int(i) for i in ni[diff]}


def _runs(new_index: I64, old_index: I64) -> list[tuple[int, int, int, int]]:
    """Maximal runs over which both index arrays step by one: (position in the arrays, first
    new index, first old index, length)."""
    if not len(new_index):
        return []
    breaks = np.flatnonzero((np.diff(new_index) != 1) | (np.diff(old_index) != 1)) + 1
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [len(new_index)]])
    return [
        (int(a), int(new_index[a]), int(old_index[a]), int(b - a))
        for a, b in zip(starts, ends, strict=True)
    ]


def replan(
    problem: Problem,
    settings: SchedulerSettings,
    *,
    changed: Collection[int] = (),
    reference: float | None = None,
) -> Replan:
    """Re-plan the instances a change affected around the running ones (module docstring).
    ``reference``: the deployed plan's value of the first objective (None: accept any
    feasible result)."""
    t0 = time.perf_counter()
    cur = problem.current
    placeable = problem.allowed.any(axis=1)
    usable = usable_current(problem)
    if not usable.any():
        return Replan(None, 0, 0, "nothing runs yet")
    fit = Fit(problem, problem.limits)
    kept = still_fitting(problem, fit, usable)
    affected = placeable & (kept < 0)
    affected[[i for i in changed if 0 <= i < problem.n_instances]] = True
    n_affected = int(affected.sum())
    limit = MAX_AFFECTED_SHARE * int(placeable.sum())
    if n_affected > limit:
        return Replan(
            None,
            n_affected,
            0,
            f"{n_affected} of {int(placeable.sum())} instances affected "
            f"(more than {MAX_AFFECTED_SHARE:.0%})",
        )
    free = affected | _neighbourhood(problem, fit, kept, affected)
    # the affected first: a neighbour takes its node back only if they left it room
    start = fill_around(
        problem, np.where(free, -1, kept), np.where(usable, cur, -1), fit, first=affected
    )
    if np.any(start[placeable] < 0):  # no room: the fewest running instances make it
        movable = (kept >= 0) & ~affected & (problem.allowed.sum(axis=1) > 1)
        made = fewest_moves(problem, np.where(affected, -1, kept), affected, fit, movable)
        if made is None:
            return Replan(
                None,
                n_affected,
                int(free.sum()),
                "the affected instances do not fit around the others, nor after the fewest "
                "moves of running instances that the nodes they prefer allow",
            )
        start = made
        free |= (start != kept) & (kept >= 0)  # moved to make room: free in the search too
    narrowed = replace(problem, allowed=freeze(_narrow(problem, fit, start, free, usable)))
    names = tuple(str(n) for n in settings.objectives)
    pp = PlacementProblem(narrowed, names, with_limits=True)
    X0 = start[pp.genes][None, :]
    out: dict[str, F64] = {}
    pp._evaluate(X0, out)
    if np.any(out["G"] > 1e-9):
        return Replan(
            None, n_affected, int(free.sum()), "the start around the others is infeasible"
        )
    X, F, _ = pareto_local_search(pp, X0, out["F"], max_moves=MAX_MOVES, max_cells=MAX_MOVE_CELLS)
    full = pp.full(X)
    front = non_dominated(F)
    k, why = choose_plan(narrowed, full[front], F[front], names, settings)
    x = full[front[k]]
    if str(settings.choice.value) == "lexicographic":
        x, _ = polish(narrowed, x, names)
    moved = int(np.sum(usable & (x != cur)))
    reason = (
        f"incremental re-plan: {n_affected} affected and {int(free.sum()) - n_affected} "
        f"neighbouring instance(s) free, {moved} running instance(s) moved; {why}"
    )
    sched = finish(problem, "nsga2", x, True, t0, reason)
    if not sched.feasible:
        return Replan(None, n_affected, int(free.sum()), "the incremental plan is infeasible")
    if stacked(problem, x[None, :]).any():  # the whole-fleet plan spreads them where it can
        why_full = "the incremental plan stacks a shared module's replicas on one node"
        return Replan(None, n_affected, int(free.sum()), why_full)
    first = names[0]
    value = sched.objectives.get(first, math.inf)
    margin = settings.migration_margin_percent / 100.0
    if reference is not None and value > reference + max(ABS_TOLERANCE, margin * abs(reference)):
        return Replan(
            None,
            n_affected,
            int(free.sum()),
            f"the incremental plan's {first} {value:.4g} is worse than the deployed "
            f"{reference:.4g} by more than the margin",
        )
    sched = replace(
        sched,
        pareto_front=F[front],
        pareto_placements=full[front],
        objective_names=names,
        duration_seconds=time.perf_counter() - t0,
    )
    return Replan(sched, n_affected, int(free.sum()), reason)


def _neighbourhood(problem: Problem, fit: Fit, kept: I64, affected: B) -> B:
    """At most ``NEIGHBOURHOOD_SHARE`` of the unaffected placed instances with a choice of
    node: largest regret first (miss probability on their node above their best allowed
    node's), then siblings of affected instances, then those that can make room: on the
    fullest nodes the affected instances may use, with room on another node."""
    candidates = (kept >= 0) & ~affected & (problem.allowed.sum(axis=1) > 1)
    idx = np.flatnonzero(candidates)
    budget = math.ceil(NEIGHBOURHOOD_SHARE * int(((kept >= 0) & ~affected).sum()))
    out = np.zeros(problem.n_instances, dtype=bool)
    if budget <= 0 or idx.size == 0:
        return out
    on = kept[idx]
    # regret: only an instance that misses on its node (uncontended) can do better elsewhere
    regret = uncontended_miss(problem, fit.allocation, idx, on)
    hot = np.flatnonzero(regret > REGRET_RESOLUTION)
    regret[regret <= REGRET_RESOLUTION] = 0.0
    if hot.size:
        regret[hot] -= best_uncontended_miss(problem, fit.allocation, idx[hot])
    homes = problem.home[affected]
    sibling = np.isin(problem.home[idx], homes[homes >= 0])
    used, _ = loads(problem, kept)
    fullness = np.max(used / np.maximum(fit.cap, 1e-9), axis=1)
    wanted: B = np.asarray(np.any(problem.allowed[affected], axis=0))
    crowd = np.where(wanted[on], fullness[on], -1.0)
    rank = np.round(regret / REGRET_RESOLUTION) * REGRET_RESOLUTION
    order = np.lexsort((idx, -crowd, -sibling.astype(float), -rank))
    taken = 0
    for k in order:
        if taken >= budget:
            break
        i = idx[k]
        if rank[k] <= 0 and not sibling[k]:
            # chosen to make room: only worth it if it has room elsewhere
            demand = fit.demand_rows(np.array([i]))[0]
            room = np.all(used + demand <= fit.cap + 1e-9, axis=1) & problem.allowed[i]
            room[on[k]] = False
            if crowd[k] < 0 or not room.any():
                continue
        out[i] = True
        taken += 1
    return out


def _narrow(problem: Problem, fit: Fit, start: I64, free: B, usable: B) -> NDArray[np.bool_]:
    """Gene spaces of the incremental search: fixed instances keep only their node; a free one
    its start, its current node and its ``CANDIDATE_NODES`` most preferred allowed nodes
    with room for it next to the start plan."""
    n_i, n_n = problem.n_instances, problem.n_nodes
    allowed = np.zeros((n_i, n_n), dtype=bool)
    fixed = np.flatnonzero((start >= 0) & ~free)
    allowed[fixed, start[fixed]] = True
    used, _ = loads(problem, start)
    rows = np.flatnonzero(free & (start >= 0))
    demand, prefs = fit.demand_rows(rows), fit.pref_rows(rows)
    for k, i in enumerate(rows):
        room = np.all(used + demand[k] <= fit.cap + 1e-9, axis=1) & problem.allowed[i]
        pref = np.where(room, prefs[k], np.inf)
        best = np.argsort(pref, kind="stable")[:CANDIDATE_NODES]
        allowed[i, best[np.isfinite(pref[best])]] = True
        allowed[i, start[i]] = True
        if usable[i]:
            allowed[i, problem.current[i]] = True
    return allowed
