"""pymoo operators over gene spaces: seeded sampling, capacity repair, mutation, crossover.

Each implements only ``_do`` and draws only from the ``random_state`` pymoo injects, so a run
is a function of its seed. Every operator keeps each gene inside its allowed set.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymoo.core.crossover import Crossover
from pymoo.core.duplicate import DuplicateElimination
from pymoo.core.mutation import Mutation
from pymoo.core.population import Population
from pymoo.core.repair import Repair
from pymoo.core.sampling import Sampling
from pymoo.operators.survival.rank_and_crowding import RankAndCrowding

from .heuristics import greedy
from .problem import PlacementProblem

__all__ = [
    "CapacityRepair",
    "FleetSampling",
    "GeneCrossover",
    "GeneDuplicates",
    "GeneMutation",
    "RankAndCrowdingSurvival",
    "binary_tournament",
    "repair_plans",
    "seed_plans",
]

I64 = NDArray[np.int64]
_EPS = 1e-9
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


class FleetSampling(Sampling):  # type: ignore[misc]
    """Initial population: seed plans first (``heuristics=True``), the rest uniform random
    within each gene's allowed set."""

    def __init__(self, heuristics: bool = True) -> None:
        super().__init__()
        self.heuristics = heuristics

    def _do(
        self,
        problem: PlacementProblem,
        n_samples: int,
        *args: Any,
        random_state: Any = None,
        **kwargs: Any,
    ) -> I64:
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
    fleet, f = pp.fleet, pp.fit
    P, N = x.shape[0], fleet.n_nodes
    valid = x >= 0
    xc = np.where(valid, x, 0)
    rows_i = np.arange(fleet.n_instances)[None, :]
    flat = (xc + N * np.arange(P)[:, None]).ravel()
    used = np.zeros((P, N, 3))
    for r in range(3):
        w = np.where(valid, f.demand[rows_i, xc, r], 0.0).ravel()
        used[:, :, r] = np.bincount(flat, weights=w, minlength=P * N).reshape(P, N)
    home = fleet.home
    off = valid & (home[None, :] >= 0) & (xc != home[None, :])
    hflat = (np.where(home >= 0, home, 0)[None, :] + N * np.arange(P)[:, None]).ravel()
    tw = np.where(off, fleet.traffic[None, :], 0.0).ravel()
    up = np.bincount(hflat, weights=tw, minlength=P * N).reshape(P, N)
    lim = np.where(f.robots, f.uplink, np.inf)
    over_node = np.any(used > f.cap[None] + _EPS, axis=2)
    over_up = up > lim[None, :] + _EPS
    if not over_node.any() and not over_up.any():
        return x
    n_i = fleet.n_instances
    cand_of = np.zeros((n_i, pp.table.shape[1]), dtype=np.int64)
    cand_of[pp.genes] = pp.table
    h_of = np.where(home >= 0, home, 0)
    # Moves only go to nodes with room and only lower uplink use, so an instance that is not
    # on an overloaded node (or a robot with its uplink over) now never will be. A second
    # pass, smallest requests first, fills what the first pass left. Each plan walks the
    # order on its own: a step moves, in every plan at once, the next instance (from that
    # plan's position in the order) that sits on an overloaded node, so the number of steps
    # is the number of such instances of the worst plan, not the number of instances.
    for order in (f.order, f.order[::-1]):
        active = np.flatnonzero(over_node.any(axis=1) | over_up.any(axis=1))
        pos = np.zeros(active.size, dtype=np.int64)
        h_ord = home[order]
        hc_ord = h_of[order][None, :]
        k_ord = np.arange(n_i)[None, :]

        def bad_of(rows: I64) -> NDArray[np.bool_]:
            """(rows, I) in ``order``: the instance sits on an overloaded node or is off
            board on a robot whose uplink is over."""
            xs = x[rows][:, order]  # noqa: B023
            v = xs >= 0
            xc = np.where(v, xs, 0)
            b = over_node[rows[:, None], xc]
            b |= (h_ord >= 0)[None, :] & (xc != h_ord[None, :]) & over_up[rows[:, None], hc_ord]  # noqa: B023
            return np.asarray(b & v, dtype=bool)

        # a plan's row changes only when the plan moves an instance
        bad_all = np.zeros((P, n_i), dtype=bool)
        bad_all[active] = bad_of(active)
        while active.size:
            bad = bad_all[active] & (k_ord >= pos[:, None])
            has = bad.any(axis=1)
            active, bad = active[has], bad[has]
            if active.size == 0:
                break
            k = np.argmax(bad, axis=1)
            pos = k + 1
            i = order[k]
            ar = np.arange(active.size)
            cur = x[active, i]
            # candidate targets: i's allowed nodes, ascending (padded with the first), so
            # argmin breaks ties towards the lowest node index as over all nodes
            cand = cand_of[i]  # (A, W)
            d = f.demand[i[:, None], cand]  # (A, W, 3)
            after = used[active[:, None], cand] + d
            at_cur = cand == cur[:, None]
            after = np.where(at_cur[:, :, None], after - d, after)
            room = np.all(after <= f.cap[cand] + _EPS, axis=2)
            h = home[i]
            hc = h_of[i]
            tr = fleet.traffic[i]
            limited = (h >= 0) & (tr > 0)
            if limited.any():
                up_base = up[active, hc] - tr * (cur != h)
                off_ok = up_base + tr <= lim[hc] + _EPS
                room &= ~limited[:, None] | off_ok[:, None] | (cand == h[:, None])
            util = np.max(after / np.maximum(f.cap[cand], _EPS), axis=2)
            score = np.where(room, f.pref[i[:, None], cand] + REPAIR_SPREAD * util, np.inf)
            jj = np.argmin(score, axis=1)
            j = cand[ar, jj]
            ok = np.isfinite(score[ar, jj]) & (j != cur)
            if not ok.any():
                continue
            rows, cur, j, i, h, hc, tr = (
                active[ok],
                cur[ok],
                j[ok],
                i[ok],
                h[ok],
                hc[ok],
                tr[ok],
            )
            used[rows, cur] -= f.demand[i, cur]
            used[rows, j] += f.demand[i, j]
            robot = h >= 0
            if robot.any():
                rr = rows[robot]
                up[rr, hc[robot]] += tr[robot] * (
                    (j[robot] != h[robot]).astype(float) - (cur[robot] != h[robot]).astype(float)
                )
                over_up[rr] = up[rr] > lim[None, :] + _EPS
            x[rows, i] = j
            over_node[rows] = np.any(used[rows] > f.cap[None] + _EPS, axis=2)
            bad_all[rows] = bad_of(rows)
    return x


class CapacityRepair(Repair):  # type: ignore[misc]
    """Capacity and uplink repair (``repair_plans``) applied to every new individual."""

    def _do(self, problem: PlacementProblem, X: NDArray[Any], **kwargs: Any) -> I64:
        full = problem.full(X)
        return repair_plans(problem, full)[:, problem.genes]


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


def _genes(pop: Any) -> I64:
    """The integer genes of a pymoo population (P, G), read off the individuals directly
    (``Population.get`` goes through several attribute look-ups per individual)."""
    return np.array([ind.X for ind in pop], dtype=np.int64).reshape(len(pop), -1)


class GeneDuplicates(DuplicateElimination):  # type: ignore[misc]
    """Exact duplicate elimination by hashing gene rows: the same decisions as pymoo's
    default (pairwise distances <= 1e-16, the first of equal rows kept) for integer genes,
    in O(P) instead of O(P^2) distances."""

    def _do(self, pop: Any, other: Any, is_duplicate: NDArray[np.bool_]) -> NDArray[np.bool_]:
        X = _genes(pop)
        if other is None:
            seen: set[bytes] = set()
            for k, row in enumerate(X):
                key = row.tobytes()
                if key in seen:
                    is_duplicate[k] = True
                else:
                    seen.add(key)
        else:
            known = {row.tobytes() for row in _genes(other)}
            for k, row in enumerate(X):
                if row.tobytes() in known:
                    is_duplicate[k] = True
        return is_duplicate


class RankAndCrowdingSurvival(RankAndCrowding):  # type: ignore[misc]
    """pymoo's NSGA-II survival with a cheaper feasible/infeasible split: one pass over the
    individuals' cached CV instead of ``split_by_feasibility``'s ``Population.get`` of F,
    CV and FEAS (which evaluates each property twice per individual). The same survivors
    in the same order: feasible ones ranked and crowded, then infeasible ones by CV."""

    def do(
        self,
        problem: Any,
        pop: Any,
        *args: Any,
        n_survive: int | None = None,
        random_state: Any = None,
        return_indices: bool = False,
        **kwargs: Any,
    ) -> Any:
        if len(pop) == 0 or not (self.filter_infeasible and problem.has_constraints()):
            return super().do(
                problem,
                pop,
                *args,
                n_survive=n_survive,
                random_state=random_state,
                return_indices=return_indices,
                **kwargs,
            )
        if random_state is None:
            random_state = np.random.default_rng()
        n = len(pop) if n_survive is None else min(n_survive, len(pop))
        cv = np.array([ind.CV[0] for ind in pop], dtype=np.float64)
        ok = cv <= pop[0].config.get("cv_eps", 0.0)
        feas = np.where(ok)[0]
        infeas = np.where(~ok)[0]
        infeas = infeas[np.argsort(cv[infeas])]
        if len(feas) == 0:
            survivors = Population()
        else:
            survivors = self._do(
                problem,
                pop[feas],
                *args,
                n_survive=min(len(feas), n),
                random_state=random_state,
                **kwargs,
            )
        if n - len(survivors) > 0:
            survivors = Population.merge(survivors, pop[infeas[: n - len(survivors)]])
        if return_indices:
            where = {ind: k for k, ind in enumerate(pop)}
            return [where[ind] for ind in survivors]
        return survivors


def binary_tournament(pop: Any, P: NDArray[Any], algorithm: Any, **kwargs: Any) -> I64:
    """pymoo's NSGA-II binary tournament (``comp_by_dom_and_crowding``), vectorised: the
    lower CV wins if either is infeasible, else the dominating plan, else the larger
    crowding distance; ties are drawn with ``algorithm.random_state.choice([a, b])`` in
    tournament order, exactly as pymoo draws them, so runs are unchanged."""
    if P.shape[1] != 2:
        raise ValueError("Only implemented for binary tournament!")
    a, b = P[:, 0], P[:, 1]
    cv = np.array([ind.CV[0] for ind in pop], dtype=np.float64)
    F = np.array([ind.F for ind in pop], dtype=np.float64)
    cd = np.array(
        [np.nan if (c := ind.data.get("crowding")) is None else c for ind in pop],
        dtype=np.float64,
    )
    S = np.full(len(P), -1, dtype=np.int64)
    tie = np.zeros(len(P), dtype=bool)
    infeasible = (cv[a] > 0.0) | (cv[b] > 0.0)
    lt, gt = cv[a] < cv[b], cv[a] > cv[b]
    S = np.where(infeasible & lt, a, np.where(infeasible & gt, b, S))
    tie |= infeasible & ~lt & ~gt
    a_better = np.any(F[a] < F[b], axis=1)
    b_better = np.any(F[b] < F[a], axis=1)
    feas = ~infeasible
    S = np.where(feas & a_better & ~b_better, a, S)
    S = np.where(feas & b_better & ~a_better, b, S)
    crowd = feas & ~(a_better ^ b_better)
    gt, lt = cd[a] > cd[b], cd[a] < cd[b]
    S = np.where(crowd & gt, a, np.where(crowd & lt, b, S))
    tie |= crowd & ~gt & ~lt
    rng = algorithm.random_state
    for k in np.flatnonzero(tie):
        S[k] = rng.choice([a[k], b[k]])
    return S[:, None]
