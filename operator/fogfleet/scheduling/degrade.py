"""Graceful degradation: a plan for a site that is short of CPU.

The limits allocation gives every instance the smallest profiled CPU that meets its deadline
(multi-robot-edge-cloud-scheduling IV-B, Fig. 3). When no placement fits those amounts, plain
Kubernetes would still run the fleet, missing some cycles; refusing it would be worse for a
warehouse than running its least important modules late. So the planner then takes instances
down their ``Ladder`` (the next smaller profiled CPU, whose execution time predicts misses),
lowest ``priority`` first and one rung at a time across a priority's instances, until a plan
fits:

1. ``steps``: the order in which rungs are taken (priority ascending; within a priority,
   every instance's first rung before anyone's second, so misses spread instead of piling on
   one instance). Hard real-time and safety-critical modules have no rungs (never degraded).
2. The shortest prefix of those steps for which a greedy packing fits is found by bisection
   (``packs``; cheap). If even every rung taken does not pack, the shortage is not CPU alone
   (memory, devices, the uplink) and the fleet stays infeasible.
3. NSGA-II plans the degraded problem (the greedy packing seeds it, so it is feasible).
4. ``give_back`` returns rungs the chosen plan has room for, highest priority first, so the
   greedy packing's pessimism costs nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem

from .evaluation import Evaluation
from .explain.shortfall import degraded_message
from .heuristics import greedy
from .objectives import constraints, evaluate
from .schedule import Schedule

__all__ = ["degrade", "give_back", "packs", "steps"]

I64 = NDArray[np.int64]
GREEDY_STYLES = ("best-fit", "level", "spread", "onboard")


def steps(problem: Problem) -> list[int]:
    """Instance indices in the order their next rung is taken (one entry per rung)."""
    lad = problem.ladder
    if lad is None or problem.priority is None:
        return []
    depth = np.where(problem.allowed, lad.depth, 0).max(axis=1)
    out: list[int] = []
    for prio in sorted({int(p) for p in problem.priority[depth > 0]}):
        group = [int(i) for i in np.flatnonzero((problem.priority == prio) & (depth > 0))]
        group.sort(key=lambda i: (problem.instances[i].module, problem.label(i)))
        for rung in range(1, int(depth[group].max()) + 1):
            out += [int(i) for i in group if depth[i] >= rung]
    return out


def levels_of(problem: Problem, order: list[int], n: int) -> I64:
    """The rungs taken per instance after the first ``n`` steps."""
    return np.bincount(np.asarray(order[:n], dtype=np.int64), minlength=problem.n_instances)


def packs(problem: Problem) -> I64 | None:
    """A plan of the greedy heuristics that satisfies every hard constraint, else None."""
    for style in GREEDY_STYLES:
        x = greedy(problem, problem.limits, style)
        if (x >= 0).all() and np.all(constraints(problem, x[None, :], problem.limits) <= 1e-9):
            return x
    return None


def give_back(problem: Problem, x: I64) -> I64:
    """Fewer rungs where plan ``x`` has CPU to spare: highest priority first, one rung at a
    time, while the instance's node keeps its requests within capacity."""
    if problem.levels is None or problem.ladder is None or problem.priority is None:
        return np.zeros(problem.n_instances, dtype=np.int64)
    lad = problem.ladder
    levels = problem.levels.copy()
    # requests per node as the load model counts them (robots' fallback reserves included)
    used = Evaluation(problem, x[None, :], problem.limits).cpu_requested[0].copy()
    held = problem.held_at_home
    prio = problem.priority
    order = sorted((int(i) for i in np.flatnonzero(levels > 0)), key=lambda i: (-prio[i], i))
    changed = True
    while changed:
        changed = False
        for i in order:
            j = int(x[i])
            if levels[i] == 0:
                continue
            now = min(int(levels[i]), int(lad.depth[i, j]))
            if now == 0:
                levels[i] = 0
                changed = True
                continue
            more = lad.cpu[i, j, now - 1] - lad.cpu[i, j, now]
            # an offloaded instance's fallback reserve on its robot grows with its rung too
            h = int(problem.home[i])
            at_home = 0.0
            if held[i] and h != j:
                k = min(int(levels[i]), int(lad.depth[i, h]))
                cap = np.inf if problem.fallback_row is None else problem.fallback_row[i, 0]
                at_home = min(lad.cpu[i, h, max(k - 1, 0)], cap) - min(lad.cpu[i, h, k], cap)
                if used[h] + at_home > problem.capacity[h, 0] + 1e-9:
                    continue
            if used[j] + more <= problem.capacity[j, 0] + 1e-9:
                used[j] += more
                if at_home:
                    used[h] += at_home
                levels[i] = now - 1
                changed = True
    return levels


def degrade(problem: Problem, solve: Callable[[Problem], Schedule]) -> Schedule | None:
    """The plan that degrades the fewest, least important instances, or None when degrading
    cannot help (an instance fits nowhere, or the shortage is not CPU)."""
    if problem.reasons:
        return None
    order = steps(problem)
    if not order or packs(problem.with_levels(levels_of(problem, order, len(order)))) is None:
        return None
    lo, hi = 0, len(order)  # lo: assumed not to pack (the full plan failed); hi: packs
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if packs(problem.with_levels(levels_of(problem, order, mid))) is not None:
            hi = mid
        else:
            lo = mid
    sched = solve(problem.with_levels(levels_of(problem, order, hi)))
    if not sched.feasible:
        return None
    x = np.asarray(sched.placement, dtype=np.int64)
    final = problem.with_levels(give_back(problem.with_levels(levels_of(problem, order, hi)), x))
    values = evaluate(
        final, x[None, :], final.limits, sched.objective_names or tuple(sched.objectives)
    )
    levels = final.levels if final.levels is not None else np.zeros(problem.n_instances, np.int64)
    return replace(
        sched,
        objectives={**sched.objectives, **{k: float(v[0]) for k, v in values.items()}},
        levels=levels,
        choice_reason=f"{sched.choice_reason}; {degraded_message(final, x)}",
    )
