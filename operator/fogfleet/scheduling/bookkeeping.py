"""pymoo's per-generation bookkeeping done on arrays: evaluation, duplicate elimination,
survival, the tournament and the current optimum. Each gives the same individuals, in the
same order, as the pymoo default it replaces (``tests/unit/scheduling/test_bookkeeping.py``
runs both); they only skip pymoo's per-individual ``Population.get``/``set``.

pymoo's ``Evaluator`` sets F and G on each individual through ``Population.set`` and leaves
the constraint violation to be computed lazily, one individual at a time, the first time
anything reads ``Individual.CV`` (``calc_cv``: about 20 us each, 10,000 times in a plan of
the warehouse fleet). ``ArrayEvaluator`` evaluates the same population in one call of the
vectorised problem and writes F, G and CV straight onto the individuals, CV by pymoo's own
default rule (the sum of the positive parts of G; no equality constraints), so every
comparison that reads it sees the same number.

``FleetNSGA2`` is pymoo's ``NSGA2`` whose current optimum (``opt``, after every generation)
reads the individuals' cached CV and rank directly instead of through ``Population.get`` of
FEAS and rank (about 1.5 ms a generation); fogfleet reads the final population, not ``opt``,
but the rule is pymoo's: the least infeasible plan while none is feasible, else the first
front.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.duplicate import DuplicateElimination
from pymoo.core.evaluator import Evaluator
from pymoo.core.individual import Individual
from pymoo.core.population import Population
from pymoo.operators.survival.rank_and_crowding import RankAndCrowding
from pymoo.util.randomized_argsort import randomized_argsort

__all__ = [
    "ArrayEvaluator",
    "FleetNSGA2",
    "GeneDuplicates",
    "RankAndCrowdingSurvival",
    "binary_tournament",
    "genes_of",
    "tournament",
    "tournament_inputs",
]

I64 = NDArray[np.int64]


class ArrayEvaluator(Evaluator):  # type: ignore[misc]
    """Evaluates F and G of the individuals not evaluated yet and sets their CV. Only for
    problems without equality constraints and populations with pymoo's default CV
    configuration (checked: anything else goes to pymoo's own path)."""

    def _eval(self, problem: Any, pop: Any, evaluate_values_of: Any, **kwargs: Any) -> None:
        if problem.n_eq_constr > 0 or pop[0].config != _DEFAULT:
            super()._eval(problem, pop, evaluate_values_of, **kwargs)
            return
        X = np.array([ind.X for ind in pop])
        out = problem.evaluate(
            X, return_values_of=evaluate_values_of, return_as_dictionary=True, **kwargs
        )
        F, G, H = out["F"], out.get("G"), out.get("H")
        no_g = G is None or G.shape[1] == 0
        cv = np.zeros(len(pop)) if no_g else np.maximum(0.0, G).sum(axis=1)
        keys = [k for k, v in out.items() if v is not None]
        # rows of the population's arrays: views, not copies (pymoo copies to let the big
        # array go early; these are a few hundred floats that live as long as the plans)
        for k, ind in enumerate(pop):
            ind.F = F[k]
            if G is not None:
                ind.G = G[k]
            if H is not None:
                ind.H = H[k]
            ind.CV = cv[k : k + 1]
            ind.evaluated.update(keys)


_DEFAULT = Individual.default_config()


class FleetNSGA2(NSGA2):  # type: ignore[misc]
    """pymoo's NSGA-II with an array-based current optimum (same individuals)."""

    def _set_optimum(self, **kwargs: Any) -> None:
        pop = self.pop
        cv = np.array([ind.CV[0] for ind in pop], dtype=np.float64)
        eps = pop[0].config.get("cv_eps", 0.0) if len(pop) else 0.0
        if not (cv <= eps).any():
            self.opt = pop[[int(np.argmin(cv))]]
        else:
            rank = np.array([ind.data.get("rank", -1) for ind in pop])
            self.opt = pop[rank == 0]


def genes_of(pop: Any) -> I64:
    """The integer genes of a pymoo population (P, G), read off the individuals directly
    (``Population.get`` goes through several attribute look-ups per individual)."""
    return np.array([ind.X for ind in pop], dtype=np.int64).reshape(len(pop), -1)


class GeneDuplicates(DuplicateElimination):  # type: ignore[misc]
    """Exact duplicate elimination by hashing gene rows: the same decisions as pymoo's
    default (pairwise distances <= 1e-16, the first of equal rows kept) for integer genes,
    in O(P) instead of O(P^2) distances."""

    def _do(self, pop: Any, other: Any, is_duplicate: NDArray[np.bool_]) -> NDArray[np.bool_]:
        X = genes_of(pop)
        if other is None:
            seen: set[bytes] = set()
            for k, row in enumerate(X):
                key = row.tobytes()
                if key in seen:
                    is_duplicate[k] = True
                else:
                    seen.add(key)
        else:
            known = {row.tobytes() for row in genes_of(other)}
            for k, row in enumerate(X):
                if row.tobytes() in known:
                    is_duplicate[k] = True
        return is_duplicate


class RankAndCrowdingSurvival(RankAndCrowding):  # type: ignore[misc]
    """pymoo's NSGA-II survival with a cheaper feasible/infeasible split: one pass over the
    individuals' cached CV instead of ``split_by_feasibility``'s ``Population.get`` of F,
    CV and FEAS (which evaluates each property twice per individual), and the ranking
    reading F and writing rank and crowding without ``Population.get``/``set``. The same
    survivors in the same order: feasible ones ranked and crowded, then infeasible ones by
    CV."""

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

    def _do(
        self,
        problem: Any,
        pop: Any,
        *args: Any,
        random_state: Any = None,
        n_survive: int | None = None,
        **kwargs: Any,
    ) -> Any:
        """Rank and crowding of the feasible individuals, as pymoo's ``RankAndCrowding``:
        whole fronts while they fit, the front that does not fit by descending crowding
        distance (ties drawn by pymoo's ``randomized_argsort``); each individual's rank and
        crowding written straight into its data."""
        F = np.array([ind.F for ind in pop], dtype=np.float64)
        n = len(pop) if n_survive is None else n_survive
        kept: list[int] = []
        for rank, front in enumerate(self.nds.do(F, n_stop_if_ranked=n)):
            overflow = len(kept) + len(front) - n
            crowding = self.crowding_func.do(F[front, :], n_remove=max(overflow, 0))
            if overflow > 0:
                by_crowding = randomized_argsort(
                    crowding, order="descending", method="numpy", random_state=random_state
                )
                chosen = front[by_crowding[:-overflow]]
            else:
                chosen = front
            for i, c in zip(front, crowding, strict=True):
                data = pop[i].data
                data["rank"] = rank
                data["crowding"] = c
            kept.extend(chosen)
        return pop[kept]


def binary_tournament(pop: Any, P: NDArray[Any], algorithm: Any, **kwargs: Any) -> I64:
    """pymoo's NSGA-II binary tournament (``comp_by_dom_and_crowding``) over a population,
    for pymoo's ``TournamentSelection`` (``tournament``)."""
    if P.shape[1] != 2:
        raise ValueError("Only implemented for binary tournament!")
    return tournament(*tournament_inputs(pop), P, algorithm.random_state)[:, None]


def tournament_inputs(
    pop: Any,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Each individual's constraint violation, objectives and crowding distance (NaN where
    survival has not set one): what ``tournament`` compares."""
    cv = np.array([ind.CV[0] for ind in pop], dtype=np.float64)
    F = np.array([ind.F for ind in pop], dtype=np.float64)
    crowding = np.array(
        [np.nan if (c := ind.data.get("crowding")) is None else c for ind in pop],
        dtype=np.float64,
    )
    return cv, F, crowding


def tournament(
    cv: NDArray[np.float64],
    F: NDArray[np.float64],
    cd: NDArray[np.float64],
    P: NDArray[Any],
    rng: np.random.Generator,
) -> I64:
    """The winners of the (n, 2) pairs ``P`` by pymoo's NSGA-II rule, vectorised: the lower
    constraint violation ``cv`` wins if either is infeasible, else the dominating plan (by
    ``F``), else the larger crowding distance ``cd``; ties are drawn with
    ``rng.choice([a, b])`` in tournament order, exactly as pymoo draws them."""
    a, b = P[:, 0], P[:, 1]
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
    for k in np.flatnonzero(tie):
        S[k] = rng.choice([a[k], b[k]])
    return S
