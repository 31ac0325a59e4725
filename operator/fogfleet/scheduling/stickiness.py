"""Keep what runs where it runs (the migration-margin rule), and the planning inputs'
fingerprint and node availability the controller re-plans on.

The scheduling core already starts its search from the current placement (STYLE.md: "the first
individual is the current placement"); this module adds the controller's promise on top: a
running instance stays where it is unless the new plan is better by
``migrationMarginPercent`` on the fleet's first objective (by default the predicted miss
rate): secondary objectives such as on-board use or balance never justify disturbing a running
module.

**Hysteresis** (issue 49). A plan that returns a running instance to the node it was last
moved off must be better by twice the margin (and twice ``ABS_TOLERANCE``): the return pays
for the move that took it away and for its own. Under one model no two placements can each
beat the other by the margin, but the model changes between re-plans: a module moved off a
node for the cycle noise learnt there starts measuring its new node afresh, while the old
node keeps what was learnt. A return then needs a gain the noise of one estimate does not
give; what the noise may fit is held back where it is learnt (``domain.observed``).

**Holding what runs** (issue 49). A learnt profile can make a running instance *ask* for more
CPU where it runs: a cycle noise of 11.6 ms on top of a pose estimator's 60 +- 6 ms puts its
row's mean + 2 std past 90 % of its 100 ms cycle, so the planner's row on that edge becomes
533m instead of 267m, and two of them no longer fit the 800m edge they run on. The rule above
then had no current placement to keep: it moved instances "to make room", with no gain to
beat, and the real-node benchmark's loop so put a pose estimator on the small edge, where it
missed more than where it ran. So when the running placement no longer fits, it is first
*held*: the same placement with the fewest rungs taken down the ladders
(``scheduling.degrade``'s order, then ``give_back``), which is how it ran or close to it, and
the new plan must beat that by the margin like any move. Only the instances whose own inputs
changed since the last decision (a learnt profile, a new cycle time) or that it already ran
below their row are held down (``decision``): a change to one module never degrades another
that was running as planned. A hard real-time or safety-critical module has no rungs, so one
that needs more CPU still moves at once.

**Each move pays for itself** (``trim_moves``). A plan that beats what runs by the margin is
taken less each of its moves that gains less than the margin on its own: the GA moves what its
search happened to move, and a whole plan that wins on one module's move would otherwise
carry the rest (seen in the e2e fallback test, 2026-11-28: the healthy robot's detector moved
on board with the degraded robot's).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import LazyLadder, Problem, freeze

from .degrade import give_back, levels_of, steps
from .evaluation import Evaluation
from .explain.shortfall import degraded_message
from .heuristics import Fit
from .objectives import feasible, objective_values

__all__ = [
    "Stickiness",
    "fill_around",
    "fingerprint",
    "hold",
    "keep_running",
    "loads",
    "mask_unavailable",
    "release_overloads",
    "release_robots",
    "still_fitting",
    "trim_moves",
    "usable_current",
]

log = logging.getLogger(__name__)
I64 = NDArray[np.int64]
# Below this absolute difference two objective values count as equal (miss rates near zero).
ABS_TOLERANCE = 1e-3
# How many times the margin a plan must beat to return an instance to the node it left.
HYSTERESIS = 2.0
# Above this many moves of running instances a plan is not trimmed move by move (trim_moves).
TRIM_MAX_MOVES = 64


def fingerprint(problem: Problem, settings: SchedulerSettings) -> str:
    """A hash of every planning input (not the current placement): same hash, same plan."""
    h = hashlib.sha256()
    h.update(
        json.dumps(
            [
                problem.fleet,
                problem.namespace,
                [dataclasses.astuple(n) for n in problem.nodes],
                [dataclasses.astuple(i) for i in problem.instances],
                settings.wire(),
            ],
            default=str,
            sort_keys=True,
        ).encode()
    )
    for f in dataclasses.fields(problem):
        value = getattr(problem, f.name)
        if f.name == "current":
            continue
        if isinstance(value, np.ndarray):
            h.update(f.name.encode())
            h.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, LazyLadder):  # what it is built from, without building it
            h.update(f.name.encode())
            h.update(value.digest)
        elif dataclasses.is_dataclass(value):
            for g in dataclasses.fields(value):
                arr = getattr(value, g.name)
                h.update(
                    np.ascontiguousarray(arr).tobytes()
                    if isinstance(arr, np.ndarray)
                    else repr(arr).encode()
                )
    return h.hexdigest()[:16]


def mask_unavailable(
    problem: Problem, unavailable: Mapping[int, str], pinned: Collection[int] = ()
) -> tuple[Problem, set[int]]:
    """Drop unavailable nodes (NotReady, cordoned, missing) from every gene space; the
    instances of a robot that is down keep the node they run on and nothing else, and so do
    those running on an unavailable node of ``pinned`` (a cluster of its own: cut off, what
    runs there runs on, so a copy elsewhere would be a duplicate).

    Returns the narrowed problem and the *stranded* instances: those that could run before
    but now have no node left (e.g. the on-board modules of a robot that is down).
    """
    if not unavailable:
        return problem, set()
    allowed = problem.allowed.copy()
    cols = sorted(unavailable)
    allowed[:, cols] = False
    allowed[np.isin(problem.current, [j for j in cols if j in pinned])] = False
    current = problem.current.copy()
    current[np.isin(current, cols)] = -1
    # a robot that is down (cut off, stopped) takes its data with it: its instances elsewhere
    # stay where they run (their node keeps their share) instead of being planned anew
    down = np.isin(problem.home, [j for j in cols if problem.tier[j] == 0])
    rows = np.flatnonzero(down)
    keep = current[rows]
    runs = keep >= 0
    runs[runs] = problem.allowed[rows[runs], keep[runs]]  # and may still run there
    allowed[rows] = False
    allowed[rows[runs], keep[runs]] = True
    stranded = {int(i) for i in np.flatnonzero(problem.allowed.any(axis=1) & ~allowed.any(axis=1))}
    reasons = dict(problem.reasons)
    for i in stranded:
        why = "; ".join(
            f"{problem.nodes[j].name} is {unavailable[j]}" for j in cols if problem.allowed[i, j]
        )
        reasons[i] = f"{problem.label(i)} has no available node: {why}"
    return dataclasses.replace(
        problem, allowed=freeze(allowed), current=freeze(current), reasons=reasons
    ), stranded


@dataclasses.dataclass(frozen=True)
class Stickiness:
    placement: I64
    migrations: list[int]  # instances moved off a node they ran on
    kept_current: bool
    reason: str
    levels: I64 | None = None  # the rungs of a held placement (``hold``); None: the plan's


def release_robots(problem: Problem, robots: Collection[int]) -> Problem:
    """The problem with the instances of ``robots`` (node indices) planned as if they did not
    run yet: the migration-margin rule keeps what runs unless the first objective improves,
    so a robot whose modules were moved on board for a bad link (``domain.linkhealth``) would
    keep them there for good once its link is healthy; released, they go where the whole
    lexicographic order of the objectives puts them with the declared link."""
    rows = np.isin(problem.home, list(robots))
    if not rows.any():
        return problem
    current = problem.current.copy()
    current[rows] = -1
    return dataclasses.replace(problem, current=current)


def _better(
    new: Mapping[str, float],
    old: Mapping[str, float],
    names: Sequence[str],
    margin: float,
    scale: float = 1.0,
) -> tuple[bool, str]:
    """Lexicographic comparison with a relative margin: the first objective that differs by more
    than ``margin`` (and ABS_TOLERANCE), both times ``scale``, decides."""
    for name in names:
        a, b = new.get(name), old.get(name)
        if a is None or b is None or not (np.isfinite(a) and np.isfinite(b)):
            continue
        diff = b - a
        if abs(diff) <= scale * max(ABS_TOLERANCE, margin * abs(b)):
            continue
        return diff > 0, f"{name} {b:.4g} -> {a:.4g}"
    return False, "no objective improves by more than the margin"


def loads(problem: Problem, x: I64) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Requested (cpu, memory, gpu) per node and off-board traffic per robot of plan ``x``,
    from the one per-node load model (``evaluation.Evaluation``) the objectives use."""
    ev = Evaluation(problem, np.asarray(x, dtype=np.int64)[None, :], problem.limits)
    used = np.stack([ev.cpu_requested[0], ev.mem_requested[0], ev.gpu_requested[0]], axis=1)
    return used, ev.offboard_traffic[0]


def fill_around(
    problem: Problem,
    fixed: I64,
    prefer: I64,
    fit: Fit | None = None,
    first: NDArray[np.bool_] | None = None,
) -> I64:
    """Place the instances that are -1 in ``fixed`` around the fixed ones: the ``prefer`` node
    if it still has room, else the allowed node with room and the lowest miss probability.
    Those with the fewest allowed nodes go first (a module pinned on board must not find its
    robot filled by one that could have gone elsewhere), then the largest CPU request first;
    the instances marked ``first`` go before all others. All -1 when one of them fits
    nowhere."""
    fit = fit or Fit(problem, problem.limits)
    x = fixed.copy()
    used, up = loads(problem, x)
    todo = np.flatnonzero((x < 0) & problem.allowed.any(axis=1))
    if todo.size == 0:
        return x
    allowed = problem.allowed[todo]
    options = allowed.sum(axis=1)
    largest = np.where(allowed, fit.allocation.cpu_request[todo], 0.0).max(axis=1)
    later = np.zeros(len(todo), dtype=bool) if first is None else ~first[todo]
    order = np.lexsort((todo, -largest, options, later))
    demand = fit.demand_rows(todo)
    pref = fit.pref_rows(todo)
    for k in order:
        i = int(todo[k])
        room = np.all(used + demand[k] <= fit.cap + 1e-9, axis=1) & allowed[k]
        h = int(problem.home[i])
        if h >= 0 and up[h] + problem.traffic[i] > fit.uplink[h] + 1e-9:
            room &= np.arange(problem.n_nodes) == h
        if not room.any():
            return np.full_like(x, -1)
        j = (
            int(prefer[i])
            if prefer[i] >= 0 and room[prefer[i]]
            else int(np.argmin(np.where(room, pref[k], np.inf)))
        )
        x[i] = j
        used[j] += demand[k, j]
        if h >= 0 and j != h:
            up[h] += problem.traffic[i]
    return x


def usable_current(problem: Problem) -> NDArray[np.bool_]:
    """(I,) the instances that run on a node they may still use."""
    cur = problem.current
    rows = np.arange(problem.n_instances)
    out: NDArray[np.bool_] = (cur >= 0) & problem.allowed[rows, np.maximum(cur, 0)]
    return out


def still_fitting(problem: Problem, fit: Fit, usable: NDArray[np.bool_]) -> I64:
    """(I,) the node of each ``usable`` running instance where it still fits with the others
    (``release_overloads`` of what runs), -1 for every other instance: what an incremental
    re-plan places the rest around."""
    running = np.where(usable, problem.current, -1).astype(np.int64)
    return release_overloads(problem, running, running, fit)


def release_overloads(problem: Problem, x: I64, new: I64, fit: Fit | None = None) -> I64:
    """Unpin instances from nodes that no longer fit them all (a module grew): first those the
    new plan moves anyway, largest CPU first, until the node fits."""
    x = x.copy()
    fit = fit or Fit(problem, problem.limits)
    placed = np.flatnonzero(x >= 0)
    need = np.zeros((problem.n_instances, 3))
    need[placed] = fit.demand_at(placed, x[placed])
    total = fit.reserve.copy()
    np.add.at(total, x[placed], need[placed])
    for j in np.flatnonzero(np.any(total > problem.capacity + 1e-9, axis=1)):
        on = [int(i) for i in np.flatnonzero(x == j)]
        load = fit.reserve[j] + need[on].sum(axis=0)
        order = sorted(on, key=lambda i: (new[i] == j, -need[i, 0]))
        for i in order:
            if np.all(load <= problem.capacity[j] + 1e-9):
                break
            load = load - need[i]
            x[i] = -1
    return x


def _revert(problem: Problem, new: I64, cur: I64, usable: NDArray[np.bool_]) -> I64:
    """Start from ``new`` and move every instance it would migrate back to its current node
    wherever that keeps the plan feasible (capacity and uplink): fewest migrations near ``new``."""
    fit = Fit(problem, problem.limits)
    x = new.copy()
    used, up = loads(problem, x)
    for _ in range(2):
        for i in np.flatnonzero(usable & (x != cur)):
            a, b, h = int(x[i]), int(cur[i]), int(problem.home[i])
            d_a, d_b = fit.demand_at(np.array([i, i]), np.array([a, b]))
            if np.any(used[b] + d_b > fit.cap[b] + 1e-9):
                continue
            d_up = (b != h) - (a != h) if h >= 0 else 0
            if h >= 0 and d_up > 0 and up[h] + problem.traffic[i] > fit.uplink[h] + 1e-9:
                continue
            used[a] -= d_a
            used[b] += d_b
            if h >= 0:
                up[h] += d_up * problem.traffic[i]
            x[i] = b
    return x


def trim_moves(
    problem: Problem,
    new: I64,
    usable: NDArray[np.bool_],
    names: Sequence[str],
    margin: float,
    with_limits: bool = True,
) -> I64:
    """``new`` without the moves that do not pay for themselves: each running instance it
    moves goes back to its current node, one at a time in index order, wherever the plan stays
    feasible and ``new`` is not better than the result by the margin (the first objective;
    module docstring). The margin rule judges a whole plan, so without this a move the fleet
    needs (a detector off a degraded link) carried moves it does not (the other robot's
    detector, which the GA happened to move too). Each undo is judged against ``new`` itself,
    so together they cost at most the margin. Above ``TRIM_MAX_MOVES`` moves ``new`` is kept
    as it is (one evaluation of the fleet per move)."""
    cur = problem.current
    x = np.asarray(new, dtype=np.int64).copy()
    moved = np.flatnonzero(usable & (x != cur))
    if len(moved) == 0 or len(moved) > TRIM_MAX_MOVES:
        return x
    planned = objective_values(problem, x, with_limits, names)
    for i in moved:
        y = x.copy()
        y[i] = cur[i]
        if not feasible(problem, y, with_limits):
            continue
        undone = objective_values(problem, y, with_limits, names)
        better, _ = _better(planned, undone, names, margin)
        if not better:
            x = y
    return x


def hold(problem: Problem, x: I64, holdable: NDArray[np.bool_]) -> Problem | None:
    """The problem (with levels) in which the running placement ``x`` fits with the fewest
    rungs taken, only by the ``holdable`` instances (module docstring), or None when it cannot
    be made to fit so."""
    base = problem.with_levels(None)
    order = [i for i in steps(base) if holdable[i]]
    if not order or not feasible(base.with_levels(levels_of(base, order, len(order))), x):
        return None
    lo, hi = -1, len(order)  # hi: fits; lo: assumed not to
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if feasible(base.with_levels(levels_of(base, order, mid)), x):
            hi = mid
        else:
            lo = mid
    return base.with_levels(give_back(base.with_levels(levels_of(base, order, hi)), x))


def _returning(moved: Sequence[int], new: I64, left: I64 | None) -> bool:
    """Whether ``new`` returns one of the ``moved`` instances to the node it last left."""
    if left is None or not moved:
        return False
    idx = np.asarray(moved, dtype=np.int64)
    return bool(((new[idx] == left[idx]) & (left[idx] >= 0)).any())


def keep_running(
    problem: Problem,
    new: I64,
    settings: SchedulerSettings,
    with_limits: bool = True,
    left: I64 | None = None,
    holdable: NDArray[np.bool_] | None = None,
) -> Stickiness:
    """Prefer the current placement of running instances over ``new`` unless ``new`` is
    better by the migration margin (twice it when ``new`` returns an instance to the node it
    was last moved off, ``left``: (I,), -1 for none; module docstring). Instances without a
    usable current node are placed around the running ones (``new``'s node when it has room).
    ``with_limits``: the plan's allocation (False for plans made for the nominal one, such as
    onboard). ``holdable`` (I,): the instances that may be held in place down their ladders
    when what runs no longer fits (``hold``; None: none)."""
    new = np.asarray(new, dtype=np.int64)
    cur = problem.current
    usable = usable_current(problem)
    moved = [int(i) for i in np.flatnonzero(usable & (new != cur))]
    if not moved:
        return Stickiness(new, [], bool(usable.any()), "nothing that runs moves")
    names = [settings.objectives[0].value]  # only the first objective justifies a move
    margin = settings.migration_margin_percent / 100.0
    back = _returning(moved, new, left)
    running = np.where(usable, cur, -1).astype(np.int64)
    placeable = problem.allowed.any(axis=1)
    if (
        holdable is not None
        and with_limits
        and (usable == placeable).all()
        and not feasible(problem, running)
    ):
        held = hold(problem, running, holdable)
        if held is not None:
            a = objective_values(problem, new, with_limits, names)
            b = objective_values(held, running, with_limits, names)
            better, why = _better(a, b, names, margin, HYSTERESIS if back else 1.0)
            if not better:
                note = degraded_message(held, running)
                return Stickiness(
                    running, [], True, f"kept running modules in place ({why}); {note}",
                    held.levels,
                )  # fmt: skip
    fit = Fit(problem, problem.limits)
    pinned = release_overloads(problem, running, new, fit)
    sticky = fill_around(problem, pinned, new, fit)
    # an instance no node may take (its robot is down) is unplaced in ``new`` too
    if ((sticky < 0) & (new >= 0)).any() or not feasible(problem, sticky, with_limits):
        sticky = _revert(problem, new, cur, usable)
    kept = [int(i) for i in np.flatnonzero(usable & (sticky != cur))]
    if (sticky >= 0).sum() == (new >= 0).sum() and feasible(problem, sticky, with_limits):
        a = objective_values(problem, new, with_limits, names)
        b = objective_values(problem, sticky, with_limits, names)
        better, why = _better(a, b, names, margin, HYSTERESIS if back else 1.0)
        if back:
            why = f"{why}, returning to a node it left (twice the margin)"
        if not better:
            note = f"; {len(kept)} had to move to make room" if kept else ""
            return Stickiness(sticky, kept, True, f"kept running modules in place ({why}){note}")
        return _trimmed(problem, new, usable, names, margin, with_limits, why)
    return _trimmed(
        problem, new, usable, names, margin, with_limits, "the current placement no longer fits"
    )


def _trimmed(
    problem: Problem,
    new: I64,
    usable: NDArray[np.bool_],
    names: Sequence[str],
    margin: float,
    with_limits: bool,
    why: str,
) -> Stickiness:
    """``new`` accepted, less the moves that do not pay for themselves (``trim_moves``)."""
    x = trim_moves(problem, new, usable, names, margin, with_limits)
    moved = [int(i) for i in np.flatnonzero(usable & (x != problem.current))]
    undone = int((usable & (new != problem.current)).sum()) - len(moved)
    note = f"; {undone} other move(s) left out, they gained less than the margin" if undone else ""
    return Stickiness(x, moved, False, f"moved {len(moved)} running module(s): {why}{note}")


def placement_array(values: Any) -> I64:
    return np.asarray(values, dtype=np.int64)
