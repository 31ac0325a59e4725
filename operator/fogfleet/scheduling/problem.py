"""The placement problem as a vectorised pymoo ``Problem``: one gene per placeable instance."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymoo.core.problem import Problem as PymooProblem

from fogfleet.api.v1alpha1.objectives import OBJECTIVE_SPECS
from fogfleet.domain.problem import Problem

from .heuristics import Fit
from .objectives import EVALUATORS, Evaluation, constraint_names

__all__ = ["FIT_TOLERANCE", "RESOLUTION", "Candidates", "PlacementProblem", "allowed_table"]

# Differences below these are noise to the search: a plan 1e-11 lower in missRate must not
# stay on the front for that alone (it would crowd out plans that differ in what matters).
RESOLUTION: dict[str, float] = {
    n: s.resolution for n, s in OBJECTIVE_SPECS.items() if s.resolution > 0
}

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
FIT_TOLERANCE = 1e-9  # a node "fits" up to this much over its capacity (repair, greedy)


@dataclass(frozen=True)
class Candidates:
    """Each instance's allowed nodes and what the repair reads of them, gathered once per
    problem (I, W[, 3]); W is the widest gene space, shorter rows padded with their first
    node. Instances outside the search keep node 0 (never looked at)."""

    node: I64  # (I, W) the allowed nodes, ascending
    demand: F64  # (I, W, 3) the instance's cpu request, memory, gpus on each
    room: F64  # (I, W, 3) each node's capacity plus the tolerance a fit allows
    scale: F64  # (I, W, 3) each node's capacity, at least the tolerance (utilisation)
    pref: F64  # (I, W) the repair's preference (``Fit.pref``): low miss, low latency


def allowed_table(allowed: NDArray[np.bool_], counts: I64, width: int) -> I64:
    """table[g, k]: the k-th allowed node of row g, ascending, padded with its first
    disallowed ones - a stable argsort of ``~allowed`` cut at ``width`` (>= every count),
    built from the allowed entries instead: at 1000 robots the argsort sorted 14 M cells into
    a 115 MB array for a table 8016 x a few wide. The padding lies in the first ``width``
    columns, which hold at most the row's count of allowed nodes."""
    n_rows = allowed.shape[0]
    table = np.zeros((n_rows, width), dtype=np.int64)

    def place(rows: I64, cols: I64, first: I64) -> None:
        # cols of each row in order, from column first[row] of the table on, up to width
        starts = np.searchsorted(rows, np.arange(n_rows))
        at = first[rows] + np.arange(len(rows)) - starts[rows]
        keep = at < width
        table[rows[keep], at[keep]] = cols[keep]

    rows, cols = np.nonzero(allowed)
    place(rows, cols, np.zeros(n_rows, dtype=np.int64))
    rows, cols = np.nonzero(~allowed[:, :width])
    place(rows, cols, counts.astype(np.int64))
    return table


class PlacementProblem(PymooProblem):  # type: ignore[misc]
    """Genes are the instances with a non-empty gene space (``genes``); the others stay at -1.

    ``_evaluate`` expands a (P, G) population into (P, I) plans and computes every objective
    and constraint for the whole population at once (``objectives.Evaluation``). With
    ``penalty`` set, constraints are not reported as G but added to every objective as
    ``penalty * sum(max(G, 0))`` (the paper's "negative reward"; used by the stand-in
    baseline only).
    """

    def __init__(
        self,
        problem: Problem,
        objectives: Sequence[str],
        *,
        with_limits: bool = True,
        penalty: float | None = None,
    ) -> None:
        unknown = [n for n in objectives if n not in EVALUATORS]
        if unknown:
            raise KeyError(f"unknown objective(s): {', '.join(unknown)}")
        self.fleet = problem
        self.alloc = problem.allocation(with_limits)
        self.with_limits = with_limits
        self.names = tuple(objectives)
        self.penalty = penalty
        self.resolution = np.array([RESOLUTION.get(n, 0.0) for n in self.names])
        self.genes: I64 = np.flatnonzero(problem.allowed.any(axis=1)).astype(np.int64)
        self.fit = Fit(problem, self.alloc)
        allowed = problem.allowed[self.genes]
        self.counts: I64 = allowed.sum(axis=1).astype(np.int64)
        width = int(self.counts.max()) if len(self.genes) else 1
        self.table: I64 = allowed_table(allowed, self.counts, width)
        n_constr = len(constraint_names(problem))
        super().__init__(
            n_var=len(self.genes),
            n_obj=len(self.names),
            n_ieq_constr=0 if penalty is not None else n_constr,
            xl=0,
            xu=max(problem.n_nodes - 1, 0),
            vtype=int,
        )

    @cached_property
    def candidates(self) -> Candidates:
        """The repair's per-instance view of its allowed nodes (``Candidates``)."""
        f = self.fit
        node = np.zeros((self.fleet.n_instances, self.table.shape[1]), dtype=np.int64)
        node[self.genes] = self.table
        inst = np.arange(self.fleet.n_instances)[:, None]
        cap = f.cap[node]
        return Candidates(
            node=node,
            demand=f.demand[inst, node],
            room=cap + FIT_TOLERANCE,
            scale=np.maximum(cap, FIT_TOLERANCE),
            pref=f.pref[inst, node],
        )

    def full(self, X: NDArray[Any]) -> I64:
        """(P, G) genes -> (P, I) plans with -1 for instances outside the search."""
        x = np.asarray(X).astype(np.int64, copy=False)
        if x.ndim == 1:
            x = x[None, :]
        out = np.full((x.shape[0], self.fleet.n_instances), -1, dtype=np.int64)
        out[:, self.genes] = x
        return out

    def random_genes(self, n: int, rng: np.random.Generator) -> I64:
        """n plans drawn uniformly within each gene's allowed set (G columns)."""
        k = (rng.random((n, len(self.genes))) * self.counts[None, :]).astype(np.int64)
        k = np.minimum(k, self.counts[None, :] - 1)
        return self.table[np.arange(len(self.genes))[None, :], k]

    def quantise(self, F: F64) -> F64:
        """Round each objective to its ``RESOLUTION``."""
        r = self.resolution[None, :]
        return np.where(r > 0, np.round(F / np.where(r > 0, r, 1.0)) * r, F)

    def objectives_of(self, X: NDArray[Any]) -> F64:
        ev = Evaluation(self.fleet, self.full(X), self.alloc)
        return np.column_stack([EVALUATORS[n](ev) for n in self.names])

    def _evaluate(self, X: NDArray[Any], out: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        ev = Evaluation(self.fleet, self.full(X), self.alloc)
        F = self.quantise(np.column_stack([EVALUATORS[n](ev) for n in self.names]))
        G = ev.constraints()
        if self.penalty is not None:
            cv = np.maximum(G, 0.0).sum(axis=1)
            out["F"] = F + self.penalty * cv[:, None]
        else:
            out["F"] = F
            out["G"] = G
