"""Pareto local search (the memetic step of ``solver.nsga2``), scored incrementally.

NSGA-II's variation rarely finds the last few single-instance moves that lower a max-type
objective such as ``reserve``: a move only helps once it is the only instance keeping the
peak node at its peak. ``pareto_local_search`` enumerates, for every plan of an archive (the
final feasible non-dominated set), all feasible one-gene moves (each instance to each other
node of its gene space) and scores them from the parent's per-node sums
(``MoveEvaluator``: only the sums at the two nodes and the robot a move touches change, so
a move costs about one pass over the nodes instead of a whole-plan evaluation); every
neighbour that no archive member weakly dominates joins the archive (and dominated members
leave it). New members are explored in the next round, until no move improves the archive,
``rounds`` have run, the work is spent or the planning budget stops it. It is deterministic:
no random draws.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from pymoo.operators.survival.rank_and_crowding.metrics import calc_crowding_distance

from .choice import dominance, non_dominated
from .objectives import EVALUATORS, NODE_OBJECTIVES, Evaluation, miss_probability
from .problem import PlacementProblem

__all__ = ["MoveEvaluator", "dominated_by", "pareto_local_search"]

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
# moves x nodes scored per call of the vectorised evaluation: bounds the memory a call uses
# (a few dozen float arrays of this many cells, ~1.6 MB each) while keeping the calls few
# enough that numpy's per-call overhead does not dominate (warehouse fleet, 11 nodes: 18k
# moves a call, local search 0.28 s instead of 0.43 s at 4096)
CHUNK_CELLS = 200_000


def dominated_by(F: F64, A: F64) -> NDArray[np.bool_]:
    """Rows of F weakly dominated by (or equal to) some row of A (minimisation)."""
    return dominance(F, A, strict=False)


def _filter_front(X: I64, F: F64) -> tuple[I64, F64]:
    """The non-dominated rows of (X, F), one per distinct objective vector (first kept)."""
    keep = non_dominated(F)
    return X[keep], F[keep]


class MoveEvaluator:
    """Objectives and constraints of single-instance moves of parent plans, incrementally.

    A move (instance i: node c -> node j) changes the per-node sums (``NODE_SUMS``: cpu and
    gpu requests, memory, expected cpu use and its on-board part; uplink traffic of i's robot)
    only at c, j and i's home, so a child's sums are its parent's with those entries patched,
    and the per-node
    objectives (F1, F2, F3, cost, energy) and the capacity/uplink constraints follow from
    them (``Evaluation.of_node_sums``: the same formulas as ``objectives.evaluate``).
    missRate and missedCycles are sums over instances of a term that depends on the node's
    contention only: where neither c nor j is contended in the parent or the child (all-active
    CPU peak within capacity and expected load within capacity: slowdown and kappa exactly 1,
    always so for feasible ``limits`` plans) only i's own term changes, to its uncontended
    value on j. Other moves are re-evaluated whole (``Evaluation``). Vectorised over the moves
    of many parents at once.
    """

    def __init__(self, pp: PlacementProblem) -> None:
        fleet, alloc = pp.fleet, pp.alloc
        self.pp = pp
        self.cap = fleet.capacity[:, 0]
        # every (instance, allowed node) pair of the search, gene by gene then node by node
        g = np.repeat(np.arange(pp.n_var), pp.counts)
        self.pair_inst: I64 = pp.genes[g]
        self.pair_node: I64 = pp.table[g, np.concatenate([np.arange(c) for c in pp.counts])]
        # uncontended per-(instance, node) terms, computed as Evaluation does at slowdown 1,
        # on the pairs only (moves never leave them), looked up by the pair's key (instance x
        # nodes + node) in sorted order: dense (I, N) tables were 2 x 115 MB at 1000 robots
        # for ~8500 pairs in an incremental re-plan (one per fixed instance, a few per free one),
        # and zero-filling them was most of its setup
        i, j = self.pair_inst, self.pair_node
        a = fleet.activation[i]
        both = fleet.net_mean[i, j] + alloc.exe_mean[i, j]
        sd = np.sqrt(alloc.exe_std[i, j] ** 2 + fleet.net_std[i, j] ** 2)
        t = both / fleet.cycle[i]
        key = i * fleet.n_nodes + j
        order = np.argsort(key, kind="stable")
        # F1's per-instance CPU (``Evaluation.cpu_onboard``): a held instance at home adds only
        # its expected use beyond its standby's share of the robot's reserve
        self._held = fleet.held_at_home if fleet.fallback_rows.size else None
        self._share = fleet.fallback_share(alloc)[:, 0]
        self._keys: I64 = key[order]
        self._miss: F64 = (a * miss_probability(both, sd, fleet.cycle[i]))[order]
        self._missed: F64 = (a * np.where(t > 1.0, t, 0.0))[order]

    def _pair_values(self, values: F64, inst: I64, node: I64) -> F64:
        """``values`` (sorted like the pair keys) of the pairs (inst, node); 0 outside them."""
        if not len(self._keys):
            return np.zeros(len(inst))
        key = inst * self.pp.fleet.n_nodes + node
        pos = np.minimum(np.searchsorted(self._keys, key), len(self._keys) - 1)
        return np.where(self._keys[pos] == key, values[pos], 0.0)

    def _onboard_use(self, inst: I64, node: I64) -> F64:
        """The expected CPU each instance adds to F1 on its node (``Evaluation.cpu_onboard``)."""
        fleet = self.pp.fleet
        w = fleet.activation[inst] * self.pp.alloc.cpu_use[inst, node]
        if self._held is None:
            return np.asarray(w, dtype=np.float64)
        held = self._held[inst] & (node == fleet.home[inst])
        return np.where(held, np.maximum(w - self._share[inst], 0.0), w)

    def parents(self, fulls: I64) -> Evaluation:
        """The parents' whole evaluation (their per-node sums are what moves patch)."""
        return Evaluation(self.pp.fleet, fulls, self.pp.alloc)

    def moves(self, fulls: I64, ev: Evaluation, limit: int) -> tuple[I64, I64, I64]:
        """(parent, instance, new node) of the one-gene moves of the plans ``fulls`` (P, I)
        that keep every capacity and uplink constraint, at most ``limit``, parent by parent,
        gene by gene, node by node. Checked from the parents' per-node sums ``ev``, so
        infeasible moves are never scored."""
        fleet, fit = self.pp.fleet, self.pp.fit
        inst, node = self.pair_inst, self.pair_node
        cur = fulls[:, inst]  # (P, K)
        ok = node[None, :] != cur
        demand = fit.demand_at(inst, node)
        for r, used in enumerate((ev.cpu_requested, ev.mem_requested, ev.gpu_requested)):
            ok &= used[:, node] + demand[:, r][None, :] <= fit.cap[node, r] + 1e-9
        home = fleet.home[inst]
        h = np.where(home >= 0, home, 0)
        delta = fleet.traffic[inst][None, :] * (
            (node != h)[None, :].astype(float) - (cur != h[None, :]).astype(float)
        )
        up = ev.offboard_traffic[:, h]
        ok &= (home < 0)[None, :] | (delta <= 0) | (up + delta <= fit.uplink[h][None, :] + 1e-9)
        par, k = np.nonzero(ok)
        par, k = par[:limit], k[:limit]
        return par.astype(np.int64), inst[k], node[k]

    @staticmethod
    def children(fulls: I64, par: I64, inst: I64, node: I64) -> I64:
        """The moved plans (M, I)."""
        out = fulls[par]
        out[np.arange(len(par)), inst] = node
        return out

    def evaluate(
        self, fulls: I64, par: I64, inst: I64, node: I64, ev: Evaluation | None = None
    ) -> tuple[dict[str, F64], F64]:
        """Every objective of ``EVALUATORS`` (M,) and the constraints G (M, C) of the plans
        fulls[par[m]] with instance inst[m] moved to node[m] (another node than its parent's):
        the same values as ``objectives.evaluate`` / ``constraints`` of those plans."""
        fleet, alloc = self.pp.fleet, self.pp.alloc
        fulls = np.asarray(fulls, dtype=np.int64)
        if fulls.ndim == 1:
            fulls = fulls[None, :]
        ev = ev if ev is not None else self.parents(fulls)
        M = len(inst)
        ar = np.arange(M)
        cur = fulls[par, inst]
        if np.any(cur < 0) or np.any(node == cur):
            raise ValueError("a move takes a placed instance to another node")

        def patch(base: F64, old: F64, new: F64) -> F64:
            out = base[par]
            out[ar, cur] -= old
            out[ar, node] += new
            return out

        # requests as the load model counts them (a fallback's home share is its robot's
        # reserve, there whatever the move: ``Fit.demand_at`` is zero there)
        d_old = self.pp.fit.demand_at(inst, cur)
        d_new = self.pp.fit.demand_at(inst, node)
        sums = {
            "cpu_requested": patch(ev.cpu_requested, d_old[:, 0], d_new[:, 0]),
            "mem_requested": patch(ev.mem_requested, d_old[:, 1], d_new[:, 1]),
            "gpu_requested": patch(ev.gpu_requested, d_old[:, 2], d_new[:, 2]),
            "cpu_expected": patch(
                ev.cpu_expected,
                fleet.activation[inst] * alloc.cpu_use[inst, cur],
                fleet.activation[inst] * alloc.cpu_use[inst, node],
            ),
            "cpu_onboard": patch(
                ev.cpu_onboard, self._onboard_use(inst, cur), self._onboard_use(inst, node)
            ),
        }
        traffic = ev.offboard_traffic[par]
        h = fleet.home[inst]
        hm = h >= 0
        delta = fleet.traffic[inst] * ((node != h).astype(float) - (cur != h).astype(float))
        traffic[ar[hm], h[hm]] += delta[hm]
        sums["offboard_traffic"] = traffic
        child = Evaluation.of_node_sums(fleet, alloc, sums)
        out = {n: EVALUATORS[n](child) for n in NODE_OBJECTIVES}
        allowed = fleet.allowed
        gene = ev.constraints()[par, -1] + (~allowed[inst, node]).astype(float)
        gene -= (~allowed[inst, cur]).astype(float)
        G = np.concatenate([child.node_constraints(), gene[:, None]], axis=1)

        # missRate / missedCycles: only i's own term changes where c and j stay uncontended
        a_valid = ev.placed_activation
        q_par = a_valid * ev.instance_miss()
        t_par = ev.tau()
        m_par = a_valid * np.where(t_par > 1.0, t_par, 0.0)
        peak = ev.cpu_peak[par]
        load = ev.cpu_expected[par]
        use_c, use_j = alloc.cpu_use[inst, cur], alloc.cpu_use[inst, node]
        cap_c, cap_j = self.cap[cur] * (1 + 1e-9), self.cap[node] * (1 + 1e-9)
        fast = (peak[ar, cur] <= cap_c) & (peak[ar, node] <= cap_j)
        fast &= (peak[ar, cur] - use_c <= cap_c) & (peak[ar, node] + use_j <= cap_j)
        fast &= (load[ar, cur] <= self.cap[cur]) & (load[ar, node] <= self.cap[node])
        fast &= sums["cpu_expected"][ar, cur] <= self.cap[cur]
        fast &= sums["cpu_expected"][ar, node] <= self.cap[node]
        # the fleet's rate is the mean over modules (Evaluation.miss_rate): a move changes
        # one term of one module's activation-weighted sum, whose weights stay the same
        weight = ev.module_activation
        counted = (weight > 0).sum(axis=1)
        w_inst = weight[par, fleet.module_index[inst]] * counted[par]
        miss_new = self._pair_values(self._miss, inst, node)
        change = (miss_new - q_par[par, inst]) / np.where(w_inst > 0, w_inst, 1.0)
        out["missRate"] = ev.miss_rate()[par] + np.where(w_inst > 0, change, 0.0)
        out["missedCycles"] = (
            m_par.sum(axis=1)[par] - m_par[par, inst] + self._pair_values(self._missed, inst, node)
        )
        slow = np.flatnonzero(~fast)
        if slow.size:
            rate, missed = self._contended(fulls, par[slow], inst[slow], cur[slow], node[slow], ev)
            out["missRate"][slow] = rate
            out["missedCycles"][slow] = missed
        # migrations: only the moved instance's own term changes
        was = fleet.current[inst]
        out["migrations"] = (
            ev.migrations()[par]
            - ((was >= 0) & (cur != was)).astype(float)
            + ((was >= 0) & (node != was)).astype(float)
        )
        return {n: out[n] for n in EVALUATORS}, G

    def _contended(
        self, fulls: I64, par: I64, inst: I64, cur: I64, node: I64, ev: Evaluation
    ) -> tuple[F64, F64]:
        """missRate and missedCycles (S,) of the moves whose nodes are or become contended.

        An instance's miss probability and cycle ratio depend only on the sums over the instances
        on its own node (the contention factor, the overlap demand: ``Evaluation.kappa``,
        ``overlap_demand``), so a move of instance i from node c to node j changes only those of
        the instances on c and j. They are evaluated in the moved plan with every other instance
        left out (the sums on c and j stay whole), and their change is added to the parent's
        figures: the same values as a whole evaluation of the moved plan, at the cost of the two
        nodes' instances (a contended 1000-robot fleet explained in a fraction of the time)."""
        fleet = self.pp.fleet
        child = self.children(fulls, par, inst, node)
        near = (child == cur[:, None]) | (child == node[:, None])  # the same instances before
        part = Evaluation(fleet, np.where(near, child, -1), self.pp.alloc)
        a = np.where(near, fleet.activation[None, :], 0.0)
        # missRate: each module's activation-weighted rate (its weights stay), averaged over the
        # modules counted (Evaluation.miss_rate)
        weight = ev.module_activation[par]  # (S, M)
        counted = (weight > 0).sum(axis=1)
        w_inst = weight[:, fleet.module_index] * counted[:, None]  # (S, I)
        before = ev.instance_miss()[par]
        change = a * (part.instance_miss() - before) / np.where(w_inst > 0, w_inst, 1.0)
        rate = ev.miss_rate()[par] + np.where(w_inst > 0, change, 0.0).sum(axis=1)
        # missedCycles: activation x cycle ratio where the cycle is overrun
        t_before, t_after = ev.tau()[par], part.tau()
        over = a * (np.where(t_after > 1.0, t_after, 0.0) - np.where(t_before > 1.0, t_before, 0.0))
        return rate, ev.missed_cycles()[par] + over.sum(axis=1)


def _score(
    me: MoveEvaluator, fulls: I64, par: I64, inst: I64, node: I64, ev: Evaluation
) -> tuple[F64, NDArray[np.bool_]]:
    """Quantised objectives of ``me.pp`` (with its penalty, if any) and feasibility."""
    pp = me.pp
    vals, G = me.evaluate(fulls, par, inst, node, ev)
    F = pp.quantise(np.column_stack([vals[n] for n in pp.names]))
    cv = np.maximum(G, 0.0).sum(axis=1)
    if pp.penalty is not None:
        F = F + pp.penalty * cv[:, None]
    return F, np.all(G <= 1e-9, axis=1)


def pareto_local_search(
    pp: PlacementProblem,
    X: I64,
    F: F64,
    *,
    rounds: int = 10,
    max_cells: int = 2_000_000,
    max_moves: int | None = None,
    max_archive: int = 300,
    stop: Callable[[], bool] | None = None,
) -> tuple[I64, F64, int]:
    """Improve the archive (X genes, F quantised objectives; feasible plans) by one-gene moves.

    The feasible moves of the archive members to explore are scored incrementally
    (``MoveEvaluator``), in batches of about ``CHUNK_CELLS`` moves x nodes. A move costs
    about one pass over the nodes, so at most ``max_cells`` (moves x nodes) of work are done,
    and at most ``max_moves`` moves when it is given: by default ~180k moves on the warehouse
    fleet (it needs ~100k), ~14k on 100 robots x 40 edges. The result depends only on the
    inputs unless ``stop`` (the planning budget, asked between batches) cuts it short.
    The archive is bounded: beyond ``max_archive`` plans it keeps the most spread ones
    (NSGA-II's crowding distance, every objective's extremes included), so a sixth or seventh
    objective does not grow the front, and the planning time, by an order of magnitude.
    Returns the new archive (non-dominated, feasible) and the number of moves scored.
    """
    X, F = _filter_front(np.asarray(X, dtype=np.int64), np.asarray(F, dtype=np.float64))
    if stop is not None and stop():
        return X, F, 0  # not even the evaluator's tables (0.4 s at 1000 robots)
    me = MoveEvaluator(pp)
    by_cells = max(max_cells // max(pp.fleet.n_nodes, 1), 1)
    max_moves = by_cells if max_moves is None else min(max_moves, by_cells)
    todo = np.ones(len(X), dtype=bool)
    n_eval = 0
    moves_per_call = CHUNK_CELLS // max(pp.fleet.n_nodes, 1)
    step = max(1, moves_per_call // max(len(me.pair_inst), 1))
    for _ in range(rounds):
        if not todo.any():
            break
        newX: list[I64] = []
        newF: list[F64] = []
        explore, explore_F = X[todo], F[todo]
        for s in range(0, len(explore), step):
            if n_eval >= max_moves or (stop is not None and stop()):
                break
            fulls = pp.full(explore[s : s + step])
            ev = me.parents(fulls)
            par, inst, node = me.moves(fulls, ev, max_moves - n_eval)
            if len(par) == 0:
                continue
            f, ok = _score(me, fulls, par, inst, node, ev)
            n_eval += len(par)
            # a child its own parent weakly dominates is out (cheap); the rest face the archive
            good = ok & ~np.all(explore_F[s : s + step][par] <= f, axis=1)
            good[good] = ~dominated_by(f[good], F)
            if good.any():
                kids = me.children(fulls, par[good], inst[good], node[good])
                newX.append(kids[:, pp.genes])
                newF.append(f[good])
        if not newX:
            break
        nX, nF = _filter_front(np.concatenate(newX), np.concatenate(newF))
        # archive members dominated by a newcomer leave
        stay = ~_strictly_dominated(F, nF)
        X = np.concatenate([X[stay], nX])
        F = np.concatenate([F[stay], nF])
        todo = np.concatenate([np.zeros(int(stay.sum()), dtype=bool), np.ones(len(nX), dtype=bool)])
        if len(X) > max_archive:
            keep = most_spread(F, max_archive)
            X, F, todo = X[keep], F[keep], todo[keep]
    return X, F, n_eval


def most_spread(F: F64, n: int) -> NDArray[np.int64]:
    """Indices of the ``n`` rows of a non-dominated F with the largest crowding distance
    (ties by index: deterministic), in their original order."""
    d = calc_crowding_distance(np.asarray(F, dtype=np.float64))
    order = np.lexsort((np.arange(len(F)), -d))  # largest distance first, then lowest index
    return np.sort(order[:n]).astype(np.int64)


def _strictly_dominated(F: F64, A: F64) -> NDArray[np.bool_]:
    """Rows of F that some row of A dominates (<= everywhere, < somewhere)."""
    return dominance(F, A)
