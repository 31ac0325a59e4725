"""Graceful degradation: a plan for a site that is short of CPU.

The limits allocation gives every instance the smallest profiled CPU that meets its deadline
(multi-robot-edge-cloud-scheduling IV-B, Fig. 3). When no placement fits those amounts, plain
Kubernetes would still run the fleet, missing some cycles; refusing it would be worse for a
warehouse than running its least important modules late. So the planner then takes instances
down their ``Ladder`` (the next smaller profiled CPU, whose execution time predicts misses),
lowest ``priority`` first and one rung at a time across a priority's instances, until a plan
fits. A site whose instances need more CPU than all its nodes have together (``short_of_cpu``)
is degraded at once; any other is searched at full CPU first (``solver.plan``).

1. ``steps``: the order in which rungs are taken (priority ascending; within a priority,
   every instance's first rung before anyone's second, so misses spread instead of piling on
   one instance). Hard real-time and safety-critical modules have no rungs (never degraded).
2. The shortest prefix of those steps for which a greedy packing fits is found by bisection
   (``packs``; cheap), stopped by the plan's time budget. If even every rung taken does not
   pack, the shortage is not CPU alone (memory, devices, the uplink) and the fleet stays
   infeasible.
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
from .heuristics import Fit, greedy
from .objectives import constraints, evaluate
from .schedule import Schedule

__all__ = ["degrade", "give_back", "least_cpu", "packs", "prefix_need", "short_of_cpu", "steps"]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
GREEDY_STYLES = ("best-fit", "level", "spread", "onboard")
SPARE_SHARES = (0.02, 0.05, 0.1, 0.2)  # the first prefixes tried: this share of the CPU spare


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


def least_cpu(problem: Problem, cpu: F64) -> F64:
    """(I,) the least of ``cpu`` (I, N) over each instance's allowed nodes: what it needs at
    the least, summed a lower bound on the site's CPU. An instance held on its robot for a
    fallback counts nothing (part of its demand there is the robot's reserve), and one with
    no allowed node nothing."""
    least: F64 = np.where(problem.allowed, cpu, np.inf).min(axis=1)
    least[~np.isfinite(least) | problem.held_at_home] = 0.0
    return least


def prefix_need(problem: Problem, order: list[int]) -> F64:
    """(len(order) + 1,) ``least_cpu`` summed after each prefix of ``order`` (every instance at
    its rung). A prefix whose bound exceeds all the nodes' CPU cannot pack."""
    lad = problem.ladder
    assert lad is not None
    rungs = lad.cpu.shape[2]
    least = np.stack([least_cpu(problem, lad.cpu[:, :, k]) for k in range(rungs)], axis=1)
    idx = np.asarray(order, dtype=np.int64)
    taken = np.zeros(problem.n_instances, dtype=np.int64)
    rung = np.empty(len(idx), dtype=np.int64)  # the rung each step takes its instance to
    for s, i in enumerate(idx):
        taken[i] += 1
        rung[s] = taken[i]
    top = rungs - 1  # the ladder is padded with its smallest row
    delta = least[idx, np.minimum(rung, top)] - least[idx, np.minimum(rung - 1, top)]
    return np.concatenate([[0.0], np.cumsum(delta)]) + float(least[:, 0].sum())


def levels_of(problem: Problem, order: list[int], n: int) -> I64:
    """The rungs taken per instance after the first ``n`` steps."""
    return np.bincount(np.asarray(order[:n], dtype=np.int64), minlength=problem.n_instances)


def packs(problem: Problem) -> I64 | None:
    """A plan of the greedy heuristics that satisfies every hard constraint, else None."""
    fit = Fit(problem, problem.limits, dense=False)  # its pair tables serve every style
    for style in GREEDY_STYLES:
        x = greedy(problem, problem.limits, style, fit)
        if (x >= 0).all() and np.all(constraints(problem, x[None, :], problem.limits) <= 1e-9):
            return x
    return None


def short_of_cpu(problem: Problem) -> bool:
    """Whether no plan can give every instance its deadline's CPU, proved by the whole site:
    ``least_cpu`` at the limits, summed, is more than every node's CPU together.
    ``solver.plan`` then degrades at once instead of searching first (at 1000 robots on 100
    edges that search took about 30 s of CPU to find nothing). A shortage on some nodes only
    is left for the search to find."""
    need = float(least_cpu(problem, problem.limits.cpu_request).sum())
    return need > float(problem.capacity[:, 0].sum()) + 1e-9


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


def _fewest_rungs(problem: Problem, order: list[int], stop: Callable[[], bool]) -> tuple[int, int]:
    """``(lo, hi)``: the prefix of ``order`` from which the greedy packing fits is in (lo,
    hi], and ``hi`` packs (every step does, ``degrade`` checked). Found by bisection, which
    ``stop()`` may end early. The bounds start from the site's CPU: prefixes whose
    ``prefix_need`` exceeds it cannot pack, and the first tries are the prefixes that leave
    2, 5, 10 and 20 % of it spare (a packing loses a little to each node's remainder), so a
    search ended early by the budget still ends near the fewest rungs, not at every rung.
    The first try is never cut, as NSGA-II's first population is not: a budget spent before
    it would take every rung, degrading high-priority modules that ``give_back`` cannot
    restore where their node is full."""
    need = prefix_need(problem, order)
    cap = float(problem.capacity[:, 0].sum())
    lo, hi = max(0, int(np.argmax(need <= cap + 1e-9)) - 1), len(order)
    tries = 0

    def fits(n: int) -> bool:
        nonlocal tries
        tries += 1
        return packs(problem.with_levels(levels_of(problem, order, n))) is not None

    def go_on() -> bool:
        return tries == 0 or not stop()

    for spare in SPARE_SHARES:
        room = need <= (1 - spare) * cap
        n = int(np.argmax(room)) if room.any() else hi
        if not lo < n < hi or not go_on():
            continue
        if fits(n):
            hi = n
            break
        lo = n
    while hi - lo > 1 and go_on():
        mid = (lo + hi) // 2
        if fits(mid):
            hi = mid
        else:
            lo = mid
    return lo, hi


def degrade(
    problem: Problem,
    solve: Callable[[Problem], Schedule],
    stop: Callable[[], bool] = lambda: False,
) -> Schedule | None:
    """The plan that degrades the fewest, least important instances, or None when degrading
    cannot help (an instance fits nowhere, or the shortage is not CPU). Once ``stop()`` says
    so (the plan's time budget), the bisection ends, after its first try, at the shortest
    prefix found to pack so far: more rungs than needed, of which ``give_back`` returns those
    the plan has room for."""
    if problem.reasons:
        return None
    order = steps(problem)
    if not order or packs(problem.with_levels(levels_of(problem, order, len(order)))) is None:
        return None
    lo, hi = _fewest_rungs(problem, order, stop)
    cut = hi - lo > 1
    taken = problem.with_levels(levels_of(problem, order, hi))
    sched = solve(taken)
    if not sched.feasible:
        return None
    x = np.asarray(sched.placement, dtype=np.int64)
    final = problem.with_levels(give_back(taken, x))
    values = evaluate(
        final, x[None, :], final.limits, sched.objective_names or tuple(sched.objectives)
    )
    levels = final.levels if final.levels is not None else np.zeros(problem.n_instances, np.int64)
    return replace(
        sched,
        objectives={**sched.objectives, **{k: float(v[0]) for k, v in values.items()}},
        levels=levels,
        choice_reason=f"{sched.choice_reason}; {degraded_message(final, x)}"
        + (
            f" (the time budget ended the search for the fewest rungs: at most {hi - lo - 1} "
            "more were taken than it would have found, and given back where the plan had room)"
            if cut
            else ""
        ),
    )
