"""Peak levelling: plans with a lower peak utilisation for the Pareto local search to start from.

``reserve`` (F2, eq. 2; ``objectives.reserve``) is the peak requested utilisation
max_{j,r} u_j^r / L_j^r, a bottleneck objective: it falls only when *every* node at the peak
is relieved at once. NSGA-II's variation and the one-gene moves of ``local`` lower it only
when a single node holds the peak, so on a large fleet whose edges fill up evenly the whole
front can sit at reserve 1.0 (measured on ``bench``'s 1000-gene stand-in: every one of the
~30 plans of the final front did, 11 % above the LP bound of the scalarised objective, while
plans at 0.90 exist).

``level(fit, x, target)`` rebuilds a plan so that no node's peak exceeds ``target``:

1. every instance on a robot that may run remotely (and whose uplink has room) joins a pool;
2. so does every instance on an edge or cloud node;
3. while the pool needs more CPU than the remote nodes offer at the target, the pool instance
   cheapest to keep on its robot goes home (F1 per core freed, eq. 1: activation x CPU use);
4. the pool is packed on the remote nodes, the most constrained (fewest allowed nodes) and
   then the largest first, each on the node whose peak after it is lowest (Graham's LPT rule
   for makespan); when one fits nowhere under the target, a few more of the cheapest go home
   and the packing starts again (``REPACKS``);
5. what step 3 sent home in batches moves back to a remote node where it still fits.

Packing the most constrained first matters (measured on the stand-in with seed 2: largest
first found no plan below a peak of 0.97 from the greedy best-fit plan, whose arm-motion
instances may go to 23 of the 50 edges only; most constrained first found one at 0.90).
An instance moves only to nodes whose uncontended miss probability is at most
``MISS_TOLERANCE`` above where it was, so levelling trades on-board use for headroom, not
missed cycles. ``levelled_plans`` bisects the target between what cannot move and the plan's
own peak, then tries a few targets above the lowest it found; the plans it finds join the
archive of the Pareto local search, which keeps the ones that no other plan dominates and
polishes them. It is deterministic, and bounded by work (``WORK_CELLS``), not by the clock.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from .heuristics import Fit
from .problem import FIT_TOLERANCE, PlacementProblem

__all__ = [
    "MISS_TOLERANCE",
    "WORK_CELLS",
    "Work",
    "level",
    "levelled_plans",
    "node_peaks",
    "pack_off_board",
    "with_levelled",
]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]

# how much higher an instance's miss probability may be where levelling moves it (measured
# on the 1000-gene stand-in: 1e-4 found no plan below a peak of 0.98, 1e-3 one at 0.905 with
# a lower missRate than the plan it started from)
MISS_TOLERANCE = 1e-3
# a pool instance that fits nowhere sends this share of the pool home before the next packing
PULL_SHARE = 0.02
REPACKS = 8
BISECTIONS = 7  # target levels tried per starting plan (the last step ~1/128 of the range)
BETWEEN = 3  # targets tried between the lowest one found and the starting plan's peak
# (instance, allowed remote node) cells the packings of one ``with_levelled`` call may look
# at: bounds its work (not the clock, so a plan is reproducible). Counted as every node of the
# fleet per pool instance before issue 46, the budget let 1000 robots x 8 modules pack twice
# (7 M cells a packing, for ~400 allowed edges among 1400 nodes): on seeds 2 and 3 both
# packings failed and no levelled plan was found (S 10-12 % above the LP bound instead of
# 5-6 %); counting the cells a packing looks at lets it pack about seven times
WORK_CELLS = 15_000_000
LATENCY_TIE = 1e-3  # weight of ``Fit.pref`` (miss, then latency) among equally loaded nodes


class Work:
    """A budget of instance x node cells, spent by each packing before it starts; ``stop``
    (the planning budget's clock, when it has one) ends it early."""

    def __init__(self, cells: int = WORK_CELLS, stop: Callable[[], bool] | None = None) -> None:
        self.left = cells
        self.stop = stop

    def take(self, cells: int) -> bool:
        """Spend ``cells`` if that many are left and ``stop`` does not say to stop."""
        if cells > self.left or (self.stop is not None and self.stop()):
            self.left = 0
            return False
        self.left -= cells
        return True


class _Loads:
    """Per-node requested loads (N, 3) and per-robot uplink traffic of one plan."""

    def __init__(self, fit: Fit, x: I64) -> None:
        p = fit.problem
        self.fit = fit
        self.cap = fit.cap
        self.u = fit.reserve.copy()
        placed = np.flatnonzero(x >= 0)
        d = fit.demand[placed, x[placed]]
        for r in range(3):
            self.u[:, r] += np.bincount(x[placed], weights=d[:, r], minlength=p.n_nodes)
        off = placed[(p.home[placed] >= 0) & (x[placed] != p.home[placed])]
        self.up = np.bincount(p.home[off], weights=p.traffic[off], minlength=p.n_nodes)

    def peak(self, nodes: I64 | int | slice = slice(None), extra: F64 | float = 0.0) -> F64:
        """Peak utilisation of ``nodes`` with ``extra`` load added (inf over a zero capacity)."""
        return _peak(self.u[nodes] + extra, self.cap[nodes])


def _peak(loads: F64, cap: F64) -> F64:
    """max over resources of load / capacity, inf where a zero capacity gets a load."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(cap > 0, loads / cap, np.where(loads > FIT_TOLERANCE, np.inf, 0.0))
    return np.asarray(ratio.max(axis=-1), dtype=np.float64)


def _floor(fit: Fit) -> float:
    """The peak no plan can go below: each node's reserve plus the instances that may run on it
    alone."""
    p = fit.problem
    only = np.flatnonzero(p.allowed.sum(axis=1) == 1)
    node = np.argmax(p.allowed[only], axis=1)
    u = fit.reserve.copy()
    d = fit.demand[only, node]
    for r in range(3):
        u[:, r] += np.bincount(node, weights=d[:, r], minlength=p.n_nodes)
    cap = fit.cap
    ratio = np.where(cap > 0, u / np.where(cap > 0, cap, 1.0), 0.0)
    return float(ratio.max()) if len(ratio) else 0.0


def level(
    fit: Fit,
    x: I64,
    target: float,
    tolerance: float = MISS_TOLERANCE,
    work: Work | None = None,
) -> I64 | None:
    """A plan like ``x`` whose every node's peak utilisation is at most ``target``, or None
    when the five steps of the module docstring find none."""
    p = fit.problem
    if work is not None and work.left == 0:
        # spent: no packing can start (an empty pool, all pulled home, is the only packing
        # that costs nothing; not worth setting up the (I, N) tables below for)
        return None
    x = np.asarray(x, dtype=np.int64).copy()
    loads = _Loads(fit, x)
    u, up = loads.u, loads.up
    top = target + FIT_TOLERANCE
    placed = x >= 0
    rows = np.arange(p.n_instances)
    q_now = np.where(placed, fit.q[rows, np.maximum(x, 0)], 1.0)
    robots = fit.robots
    near = fit.q <= q_now[:, None] + tolerance
    remote_ok = p.allowed & ~robots[None, :] & near & placed[:, None]
    pool: list[int] = []
    # 1. every instance on a robot that may run remotely leaves it, largest first (grouped by
    # robot once: a mask over the (I, N) table per robot was most of a 1000-robot plan)
    movable = np.flatnonzero(remote_ok.any(axis=1) & placed)
    movable = movable[robots[x[movable]]]
    by_robot = movable[np.argsort(x[movable], kind="stable")]
    cuts = np.searchsorted(x[by_robot], np.flatnonzero(robots))
    ends = np.append(cuts[1:], len(by_robot))
    for h, a, b in zip(np.flatnonzero(robots), cuts, ends, strict=True):
        mine = by_robot[a:b]
        for i in mine[np.argsort(-fit.demand[mine, h, 0], kind="stable")]:
            if p.home[i] == h and up[h] + p.traffic[i] > fit.uplink[h] + FIT_TOLERANCE:
                continue
            u[h] -= fit.demand[i, h]
            up[h] += p.traffic[i] if p.home[i] == h else 0.0
            x[i] = -2
            pool.append(int(i))
        if loads.peak(int(h)) > top:
            return None
    # 2. every instance on a remote node joins the pool
    on_remote = np.flatnonzero((x >= 0) & ~robots[np.maximum(x, 0)])
    for r in range(3):
        u[:, r] -= np.bincount(
            x[on_remote], weights=fit.demand[on_remote, x[on_remote], r], minlength=p.n_nodes
        )
    x[on_remote] = -2
    members = np.array(sorted(pool + on_remote.tolist()), dtype=np.int64)
    if not len(members):
        return x if loads.peak().max() <= top else None
    # 3. the cheapest to keep on board go home until the pool's CPU fits the remote nodes
    core = np.where(remote_ok[members], fit.demand[members, :, 0], np.inf).min(axis=1)
    home = p.home[members]
    can_home = (
        (home >= 0) & p.allowed[members, np.maximum(home, 0)] & near[members, np.maximum(home, 0)]
    )
    f1 = p.activation[members] * fit.allocation.cpu_use[members, np.maximum(home, 0)]
    f1 = f1 / np.maximum(fit.cap[np.maximum(home, 0), 0], FIT_TOLERANCE)
    order = np.flatnonzero(can_home)[
        np.argsort((f1 / np.maximum(core, FIT_TOLERANCE))[can_home], kind="stable")
    ]
    in_pool = np.ones(len(members), dtype=bool)
    room = target * fit.cap[~robots, 0].sum()
    queue = list(order)

    def pull(count: int) -> bool:
        """Send up to ``count`` of the cheapest pool instances home (where they fit)."""
        pulled = 0
        while queue and pulled < count:
            k = queue.pop(0)
            i, h = int(members[k]), int(home[k])
            if loads.peak(h, fit.demand[i, h]) > top:
                continue
            u[h] += fit.demand[i, h]
            up[h] -= p.traffic[i]
            x[i] = h
            in_pool[k] = False
            pulled += 1
        return pulled > 0

    while core[in_pool].sum() > room:
        if not pull(1):
            return None
    # 4. pack the pool largest first (LPT); pull more home and repack when one does not fit
    for _ in range(REPACKS):
        if work is not None and not work.take(int(remote_ok[members[in_pool]].sum())):
            return None
        packed = _pack(fit, loads, members[in_pool], remote_ok, top)
        if packed is not None:
            x[members[in_pool]] = packed
            _offload(fit, loads, x, remote_ok, top)
            return x
        if not pull(max(1, int(PULL_SHARE * in_pool.sum()))):
            return None
    return None


def _pack(fit: Fit, loads: _Loads, pool: I64, allowed: NDArray[np.bool_], top: float) -> I64 | None:
    """Nodes for ``pool`` by the LPT rule under ``top`` (``loads.u`` then includes them), or
    None (``loads.u`` left as it was)."""
    u = loads.u.copy()
    share = np.where(allowed[pool], fit.demand[pool, :, 0] / np.maximum(fit.cap[:, 0], 1e-12), 0.0)
    out = np.empty(len(pool), dtype=np.int64)
    order = np.lexsort((-share.max(axis=1), allowed[pool].sum(axis=1)))
    # each instance looks at its allowed nodes only (ascending: ties go to the lowest node)
    rows, cols = np.nonzero(allowed[pool])
    starts = np.searchsorted(rows, np.arange(len(pool) + 1))
    for k in order:
        i = pool[k]
        c = cols[starts[k] : starts[k + 1]]
        if not len(c):
            return None
        score = _peak(u[c] + fit.demand[i, c], fit.cap[c])
        best = float(score.min())
        if best > top:
            return None
        near = score <= best + 1e-3
        j = int(c[np.argmin(np.where(near, score + LATENCY_TIE * fit.pref[i, c], np.inf))])
        out[k] = j
        u[j] += fit.demand[i, j]
    loads.u = u
    return out


def node_peaks(fit: Fit, x: I64) -> F64:
    """Each node's peak utilisation under the plan ``x`` (its reserve included)."""
    return _Loads(fit, np.asarray(x, dtype=np.int64)).peak()


def pack_off_board(fit: Fit, x: I64, pool: I64, allowed: NDArray[np.bool_]) -> I64 | None:
    """``x`` with the instances ``pool`` (unplaced in ``x``) packed on their ``allowed`` nodes by
    step 4's LPT rule, every node up to its capacity; None where one fits nowhere
    (``configurations.priced_plans``)."""
    x = np.asarray(x, dtype=np.int64).copy()
    packed = _pack(fit, _Loads(fit, x), pool, allowed, 1.0 + FIT_TOLERANCE)
    if packed is None:
        return None
    x[pool] = packed
    return x


def _offload(fit: Fit, loads: _Loads, x: I64, remote_ok: NDArray[np.bool_], top: float) -> None:
    """Step 5: what is on board and may run remotely moves to a remote node with room under
    ``top``, largest on-board use (F1) first (pulling home in batches overshoots)."""
    p = fit.problem
    kept = np.flatnonzero((x >= 0) & (x == p.home) & remote_ok.any(axis=1))
    f1 = p.activation[kept] * fit.allocation.cpu_use[kept, x[kept]]
    for i in kept[np.argsort(-f1 / fit.cap[x[kept], 0], kind="stable")]:
        h = int(x[i])
        if loads.up[h] + p.traffic[i] > fit.uplink[h] + FIT_TOLERANCE:
            continue
        c = np.flatnonzero(remote_ok[i])
        if not len(c):
            continue
        score = _peak(loads.u[c] + fit.demand[i, c], fit.cap[c])
        j = int(c[np.argmin(score)])
        if score.min() > top:
            continue
        loads.u[h] -= fit.demand[i, h]
        loads.u[j] += fit.demand[i, j]
        loads.up[h] += p.traffic[i]
        x[i] = j


def levelled_plans(
    fit: Fit,
    x: I64,
    bisections: int = BISECTIONS,
    between: int = BETWEEN,
    work: Work | None = None,
) -> list[I64]:
    """Plans from ``x``: the lowest target peak found by bisecting between ``_floor`` and
    ``x``'s own peak, then ``between`` targets evenly spaced above it (the objectives trade
    headroom for on-board use, and the best trade is rarely at either end)."""
    top = float(_Loads(fit, x).peak().max())
    lo, hi = min(_floor(fit), top), top
    found: list[I64] = []
    for _ in range(bisections):
        mid = (lo + hi) / 2
        y = level(fit, x, mid, work=work)
        if y is None:
            lo = mid
            continue
        found.append(y)
        hi = min(mid, float(_Loads(fit, y).peak().max()))
    if found:
        for k in range(1, between + 1):
            y = level(fit, x, hi + (top - hi) * k / (between + 1), work=work)
            if y is not None:
                found.append(y)
    return found


def with_levelled(
    pp: PlacementProblem, X: I64, F: F64, stop: Callable[[], bool] | None = None
) -> tuple[I64, F64]:
    """The archive (genes, objectives) plus the feasible levelled plans of its members that
    are best in some objective other than ``reserve`` (nothing added without ``reserve``);
    ``stop`` (the planning budget) ends the packings early, checked before each."""
    if "reserve" not in pp.names or not len(X) or (stop is not None and stop()):
        return X, F
    starts = sorted({int(np.argmin(F[:, k])) for k, n in enumerate(pp.names) if n != "reserve"})
    full = pp.full(X)
    work = Work(stop=stop)
    extra = [y for s in starts for y in levelled_plans(pp.fit, full[s], work=work)]
    if not extra:
        return X, F
    genes = np.stack(extra)[:, pp.genes]
    out: dict[str, F64] = {}
    pp._evaluate(genes, out)
    ok = np.maximum(out["G"], 0.0).sum(axis=1) <= 1e-9
    return np.concatenate([X, genes[ok]]), np.concatenate([F, out["F"][ok]])
