"""pymoo operators over gene spaces: seeded sampling, capacity repair, mutation, crossover
(the bookkeeping around them, on arrays: ``bookkeeping``, ``mating``).

Each implements only ``_do`` and draws only from the ``random_state`` pymoo injects, so a run
is a function of its seed. Every operator keeps each gene inside its allowed set.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymoo.core.crossover import Crossover
from pymoo.core.mutation import Mutation
from pymoo.core.repair import Repair
from pymoo.core.sampling import Sampling

from .heuristics import greedy
from .problem import FIT_TOLERANCE, PlacementProblem
from .spread import spread_plans

__all__ = [
    "CapacityRepair",
    "FleetSampling",
    "GeneCrossover",
    "GeneMutation",
    "repair_plans",
    "seed_plans",
    "warm_population",
]

I64 = NDArray[np.int64]
_EPS = FIT_TOLERANCE
# weight of the target node's peak utilisation after a move, next to its miss probability and
# 0.01 * cycle ratio (``Fit.pref``): spreads repaired instances over the emptier nodes
REPAIR_SPREAD = 0.02


def seed_plans(pp: PlacementProblem) -> list[I64]:
    """Constructive plans (full I columns): the current placement (completed greedily), then
    greedy best-fit by miss probability, on-board first, spread and level; duplicates dropped."""
    fleet = pp.fleet
    best = greedy(fleet, pp.alloc, "best-fit", pp.fit)
    plans: list[I64] = []
    if (fleet.current >= 0).any():
        plans.append(np.where(fleet.current >= 0, fleet.current, best).astype(np.int64))
    plans += [
        best,
        greedy(fleet, pp.alloc, "onboard", pp.fit),
        greedy(fleet, pp.alloc, "spread", pp.fit),
        greedy(fleet, pp.alloc, "level", pp.fit),
    ]
    out: list[I64] = []
    for p in plans:
        if not any(np.array_equal(p, q) for q in out):
            out.append(p)
    return out


# From this many genes on, the individuals after the seed plans are the seeds with a few genes
# re-drawn instead of uniform random plans (``warm_population``). Measured on 1000 robots x 8
# modules (8000 genes, ~400 allowed nodes each): the 95 random plans overloaded most nodes, and
# repairing them took longer than the 20 s time budget, so NSGA-II ran a single generation;
# none of them reached the final front. Below it (the warehouse's 40 genes, the 1000-gene
# stand-in) random plans are cheap to repair and add diversity, so nothing changes there.
WARM_START_GENES = 2000
WARM_START_SHARE = 0.002  # of the genes re-drawn in each warm individual


def warm_population(
    pp: PlacementProblem, seeds: I64, n: int, rng: np.random.Generator, share: float
) -> I64:
    """``n`` plans (G columns), each a copy of a seed (``seeds``: (S, G), taken in turn) with
    each gene re-drawn uniformly within its allowed set with probability ``share`` (at least
    one gene): a population around the constructive plans that the repair fixes in a few moves
    (NSGA-II's warm start; multi-robot-edge-cloud-scheduling III-C keeps the GA itself)."""
    out = seeds[np.arange(n) % len(seeds)].copy()
    if not n or not out.shape[1]:
        return out
    redraw = rng.random(out.shape) < share
    redraw[np.arange(n), rng.integers(out.shape[1], size=n)] = True
    fresh = pp.random_genes(n, rng)
    out[redraw] = fresh[redraw]
    return out


class FleetSampling(Sampling):  # type: ignore[misc]
    """Initial population: seed plans first (``heuristics=True``), the rest uniform random
    within each gene's allowed set, or from ``WARM_START_GENES`` genes on the seeds with a
    few genes re-drawn (``warm_population``)."""

    def __init__(self, heuristics: bool = True, warm: bool | None = None) -> None:
        super().__init__()
        self.heuristics = heuristics
        self.warm = warm  # None: from WARM_START_GENES genes on

    def warm_for(self, problem: PlacementProblem) -> bool:
        """Whether this sampling warm-starts ``problem``'s population."""
        if not self.heuristics:
            return False
        return problem.n_var >= WARM_START_GENES if self.warm is None else self.warm

    def _do(
        self,
        problem: PlacementProblem,
        n_samples: int,
        *args: Any,
        random_state: Any = None,
        **kwargs: Any,
    ) -> I64:
        if self.warm_for(problem):
            # repaired once here, not in every copy: a greedy plan of 1000 robots overloads
            # nodes (best-fit peaks at 1.33), and repairing 20 copies of each cost seconds
            full = np.stack(seed_plans(problem)[:n_samples])
            full = spread_plans(problem.fleet, repair_plans(problem, full), problem.fit)
            first = full[:, problem.genes]
            rest = warm_population(
                problem, first, n_samples - len(first), random_state, WARM_START_SHARE
            )
            return np.concatenate([first, rest])
        X = problem.random_genes(n_samples, random_state)
        if self.heuristics:
            seeds = seed_plans(problem)[:n_samples]
            for k, plan in enumerate(seeds):
                X[k] = plan[problem.genes]
        return X


def repair_plans(pp: PlacementProblem, x: I64) -> I64:
    """Move instances off overloaded nodes (and off-board instances of robots whose uplink is
    over 80%) to allowed nodes with room, preferring low miss probability and low latency.

    Vectorised over plans: a pass over the instances (largest CPU request first, then a
    second pass smallest first if needed) and, in each step, every plan in which that
    instance sits on an overloaded node moves it at once.
    An instance with no allowed node that has room stays (the plan stays infeasible).
    ``x`` is (P, I) and is modified in place.
    """
    loads = _Loads.of(pp, x)
    if not loads.over_node.any() and not loads.over_up.any():
        return x
    # Moves only go to nodes with room and only lower uplink use, so an instance that is not
    # on an overloaded node (or a robot with its uplink over) now never will be. A second
    # pass, smallest requests first, fills what the first pass left.
    for order in (pp.fit.order, pp.fit.order[::-1]):
        _RepairPass(pp, x, loads, order).run()
    return x


@dataclass
class _Loads:
    """What a population of plans puts on each node and uplink (P, N), kept up to date as the
    repair moves instances."""

    used: NDArray[np.float64]  # (P, N, 3) requested cpu, memory, gpus (fallback reserves too)
    up: NDArray[np.float64]  # (P, N) off-board traffic of each robot
    lim: NDArray[np.float64]  # (N,) the uplink limit of each robot, inf for other nodes
    over_node: NDArray[np.bool_]  # (P, N) a node over its capacity
    over_up: NDArray[np.bool_]  # (P, N) a robot over its uplink limit

    @classmethod
    def of(cls, pp: PlacementProblem, x: I64) -> _Loads:
        fleet, f = pp.fleet, pp.fit
        P, N = x.shape[0], fleet.n_nodes
        valid = x >= 0
        xc = np.where(valid, x, 0)
        rows_i = np.arange(fleet.n_instances)[None, :]
        flat = (xc + N * np.arange(P)[:, None]).ravel()
        used = np.repeat(f.reserve[None], P, axis=0)  # robots' fallback reserves first
        for r in range(3):
            w = np.where(valid, f.demand[rows_i, xc, r], 0.0).ravel()
            used[:, :, r] += np.bincount(flat, weights=w, minlength=P * N).reshape(P, N)
        home = fleet.home
        off = valid & (home[None, :] >= 0) & (xc != home[None, :])
        hflat = (np.where(home >= 0, home, 0)[None, :] + N * np.arange(P)[:, None]).ravel()
        tw = np.where(off, fleet.traffic[None, :], 0.0).ravel()
        counts = np.bincount(hflat, weights=tw, minlength=P * N).reshape(P, N)
        up = np.asarray(counts, dtype=np.float64)  # float64 already (weights): for mypy
        lim = np.where(f.robots, f.uplink, np.inf)
        over_node = np.any(used > f.cap[None] + _EPS, axis=2)
        over_up = up > lim[None, :] + _EPS
        return cls(used, up, lim, over_node, over_up)


class _RepairPass:
    """One pass of the repair over the instances in ``order``.

    Each plan walks the order on its own: a step moves, in every plan at once, the next
    instance (from that plan's position in the order) that sits on an overloaded node, so the
    number of steps is the number of such instances of the worst plan, not the number of
    instances."""

    def __init__(self, pp: PlacementProblem, x: I64, loads: _Loads, order: I64) -> None:
        self.pp, self.x, self.loads, self.order = pp, x, loads, order
        home = pp.fleet.home
        self.home_col = np.where(home >= 0, home, 0)  # an instance's robot, 0 if shared
        self.h_ord = home[order][None, :]
        self.hc_ord = self.home_col[order][None, :]
        self.robot_ord = self.h_ord >= 0
        self.x_ord = x[:, order]  # the plans in this pass's order, kept in step with x
        # (P, I) in ``order``: a plan's row changes only when the plan moves an instance
        self.bad_all = np.zeros((x.shape[0], pp.fleet.n_instances), dtype=bool)

    def bad_of(self, rows: I64) -> NDArray[np.bool_]:
        """(rows, I) in ``order``: the instance sits on an overloaded node or is off board on
        a robot whose uplink is over."""
        xs = self.x_ord[rows]
        v = xs >= 0
        xc = np.where(v, xs, 0)
        b = self.loads.over_node[rows[:, None], xc]
        ou = self.loads.over_up[rows]
        if ou.any():  # rare: only a robot's uplink over
            away = self.robot_ord & (xc != self.h_ord)
            b |= away & ou[np.arange(len(rows))[:, None], self.hc_ord]
        return np.asarray(b & v, dtype=bool)

    def run(self) -> None:
        loads, order = self.loads, self.order
        active = np.flatnonzero(loads.over_node.any(axis=1) | loads.over_up.any(axis=1))
        pos = np.zeros(active.size, dtype=np.int64)
        k_ord = np.arange(self.pp.fleet.n_instances)[None, :]
        self.bad_all[active] = self.bad_of(active)
        while active.size:
            bad = self.bad_all[active] & (k_ord >= pos[:, None])
            has = bad.any(axis=1)
            active, bad = active[has], bad[has]
            if active.size == 0:
                break
            k = np.argmax(bad, axis=1)
            pos = k + 1
            i = order[k]
            cur = self.x[active, i]
            j, ok = self.targets(active, i, cur)
            if ok.any():
                self.move(active[ok], cur[ok], j[ok], i[ok], k[ok])

    def targets(self, active: I64, i: I64, cur: I64) -> tuple[I64, NDArray[np.bool_]]:
        """For each active plan, the best node with room for its instance ``i`` (lowest miss
        probability and latency, then the emptier node) and whether it is a move at all."""
        fleet, c, loads = self.pp.fleet, self.pp.candidates, self.loads
        ar = np.arange(active.size)
        # candidate targets: i's allowed nodes, ascending (padded with the first), so
        # argmin breaks ties towards the lowest node index as over all nodes
        cand = c.node[i]  # (A, W)
        d = c.demand[i]  # (A, W, 3)
        after = loads.used[active[:, None], cand] + d
        at_cur = cand == cur[:, None]
        after = np.where(at_cur[:, :, None], after - d, after)
        room = _all3(after <= c.room[i])
        h = fleet.home[i]
        hc = self.home_col[i]
        tr = fleet.traffic[i]
        limited = (h >= 0) & (tr > 0)
        if limited.any():
            up_base = loads.up[active, hc] - tr * (cur != h)
            off_ok = up_base + tr <= loads.lim[hc] + _EPS
            room &= ~limited[:, None] | off_ok[:, None] | (cand == h[:, None])
        util = _max3(after / c.scale[i])
        score = np.where(room, c.pref[i] + REPAIR_SPREAD * util, np.inf)
        jj = np.argmin(score, axis=1)
        j = cand[ar, jj]
        ok = np.isfinite(score[ar, jj]) & (j != cur)
        return j, ok

    def move(self, rows: I64, cur: I64, j: I64, i: I64, k: I64) -> None:
        """Move instance ``i`` (position ``k`` in the order) from ``cur`` to ``j`` in plans
        ``rows``; update the loads and the rows whose overloads changed."""
        fleet, f, loads = self.pp.fleet, self.pp.fit, self.loads
        h, hc, tr = fleet.home[i], self.home_col[i], fleet.traffic[i]
        loads.used[rows, cur] -= f.demand[i, cur]
        loads.used[rows, j] += f.demand[i, j]
        robot = h >= 0
        changed = np.zeros(rows.size, dtype=bool)
        if robot.any():
            rr = rows[robot]
            loads.up[rr, hc[robot]] += tr[robot] * (
                (j[robot] != h[robot]).astype(float) - (cur[robot] != h[robot]).astype(float)
            )
            was = loads.over_up[rr, hc[robot]]
            loads.over_up[rr] = loads.up[rr] > loads.lim[None, :] + _EPS
            changed[robot] = was != loads.over_up[rr, hc[robot]]
        self.x[rows, i] = j
        self.x_ord[rows, k] = j
        # only the two nodes of a move change (j had room: it stays within capacity)
        was = loads.over_node[rows, cur]
        loads.over_node[rows, cur] = _any3(loads.used[rows, cur] > f.cap[cur] + _EPS)
        loads.over_node[rows, j] = _any3(loads.used[rows, j] > f.cap[j] + _EPS)
        changed |= was != loads.over_node[rows, cur]
        # the moved instance now sits on a node with room and within its robot's uplink;
        # the others' rows only change where a node or an uplink stopped being over
        self.bad_all[rows, k] = False
        if changed.any():
            self.bad_all[rows[changed]] = self.bad_of(rows[changed])


def _all3(b: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """``b.all(axis=-1)`` for the three resources (cpu, memory, gpu): three slices are
    several times cheaper than numpy's reduction over a length-3 axis."""
    return np.asarray(b[..., 0] & b[..., 1] & b[..., 2], dtype=bool)


def _any3(b: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """``b.any(axis=-1)`` for the three resources (see ``_all3``)."""
    return np.asarray(b[..., 0] | b[..., 1] | b[..., 2], dtype=bool)


def _max3(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a.max(axis=-1)`` for the three resources (see ``_all3``)."""
    return np.asarray(np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2]), dtype=np.float64)


class CapacityRepair(Repair):  # type: ignore[misc]
    """Capacity and uplink repair (``repair_plans``), then the shared replicas' spread
    (``spread.spread_plans``), applied to every new individual."""

    def _do(self, problem: PlacementProblem, X: NDArray[Any], **kwargs: Any) -> I64:
        full = repair_plans(problem, problem.full(X))
        return spread_plans(problem.fleet, full, problem.fit)[:, problem.genes]


class GeneMutation(Mutation):  # type: ignore[misc]
    """Re-draws genes uniformly within their allowed sets.

    ``prob`` is the chance that an offspring mutates (fogfleet: settings.mutationPercent);
    a mutating offspring re-draws each gene with probability ``per_gene`` (default 1/G) and
    at least one gene. The paper's PyGAD
    setting is prob=1, per_gene=0.3.
    """

    def __init__(self, prob: float = 0.3, per_gene: float | None = None) -> None:
        super().__init__(prob=prob)
        self.per_gene = per_gene

    def _do(
        self,
        problem: PlacementProblem,
        X: NDArray[Any],
        *args: Any,
        random_state: Any = None,
        **kwargs: Any,
    ) -> I64:
        rng: np.random.Generator = random_state
        x: I64 = np.asarray(X).astype(np.int64)
        n, g = x.shape
        if g == 0:
            return x
        rate = self.per_gene if self.per_gene is not None else 1.0 / g
        mask = rng.random((n, g)) < rate
        mask[np.arange(n), rng.integers(0, g, size=n)] = True
        fresh = problem.random_genes(n, rng)
        return np.where(mask, fresh, x)


class GeneCrossover(Crossover):  # type: ignore[misc]
    """Two parents, two children: ``uniform`` (each gene from either parent with p = 1/2) or
    ``single_point`` (the paper's PyGAD setting)."""

    def __init__(self, kind: str = "uniform", prob: float = 0.9) -> None:
        if kind not in ("uniform", "single_point"):
            raise ValueError(f"unknown crossover {kind!r}")
        super().__init__(2, 2, prob=prob)
        self.kind = kind

    def _do(
        self,
        problem: PlacementProblem,
        X: NDArray[Any],
        *args: Any,
        random_state: Any = None,
        **kwargs: Any,
    ) -> I64:
        rng: np.random.Generator = random_state
        a, b = np.asarray(X[0]).astype(np.int64), np.asarray(X[1]).astype(np.int64)
        m, g = a.shape
        if self.kind == "uniform" or g < 2:
            mask = rng.random((m, g)) < 0.5
        else:
            cut = np.asarray(rng.integers(1, g, size=m), dtype=np.int64)
            mask = np.arange(g)[None, :] < cut[:, None]
        return np.stack([np.where(mask, a, b), np.where(mask, b, a)])
