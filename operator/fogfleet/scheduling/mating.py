"""NSGA-II's mating on gene arrays: selection, crossover, mutation, repair and duplicate
elimination of a whole generation's offspring without pymoo's per-individual objects.

pymoo's ``Mating`` builds a ``Population`` of ``Individual`` objects after every step and
reads the genes back out of them (``Population.get``, ``Population.set``, ``merge``), and it
repeats selection-to-deduplication for every handful of offspring that duplicate elimination
threw away. On the warehouse fleet that bookkeeping and the repeated small repairs were about
half of the planning time (``make bench``: decision time). ``ArrayMating`` keeps the genes in
one (n, G) array from the parents' selection to the deduplicated offspring and makes the
``Population`` once.

With ``oversample=1`` it draws exactly what pymoo's ``Mating`` draws, in the same order
(the tournament's permutations and ties, the crossover mask, the mutation mask), so the
evolution is the same plan for plan (``tests/unit/scheduling/test_bookkeeping.py`` checks it);
``oversample > 1`` makes that many more offspring per round than still missing, so the
duplicates that elimination removes are usually already covered and a generation needs one
repair instead of several.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymoo.core.infill import InfillCriterion
from pymoo.core.population import Population
from pymoo.core.variable import get
from pymoo.util.misc import random_permutations

from .bookkeeping import genes_of, tournament, tournament_inputs
from .operators import CapacityRepair, GeneCrossover, GeneMutation
from .problem import PlacementProblem

__all__ = ["DEFAULT_OVERSAMPLE", "ArrayMating"]

I64 = NDArray[np.int64]
# offspring made per round, as a multiple of those still missing. On the warehouse fleet
# pymoo's mating had to re-mate about 9 of every 100 offspring (duplicates of a parent or of
# another child); 1.25 covers that in one round: 100 repairs per plan instead of 227.
DEFAULT_OVERSAMPLE = 1.25
TOURNAMENT_PRESSURE = 2  # binary tournament, as NSGA-II


class ArrayMating(InfillCriterion):  # type: ignore[misc]
    """Binary tournament (``bookkeeping.tournament``), ``GeneCrossover`` with its probability,
    ``GeneMutation`` with its probability, ``CapacityRepair``, exact duplicate elimination
    against the parents and the offspring so far; rounds until ``n_offsprings`` unique
    offspring exist or ``n_max_iterations`` rounds have run (pymoo's rule)."""

    def __init__(
        self,
        crossover: GeneCrossover,
        mutation: GeneMutation,
        repair: CapacityRepair | None,
        *,
        oversample: float = DEFAULT_OVERSAMPLE,
        n_max_iterations: int = 100,
    ) -> None:
        if oversample < 1.0:
            raise ValueError(f"oversample must be at least 1, got {oversample}")
        super().__init__(n_max_iterations=n_max_iterations)
        self.crossover = crossover
        self.mutation = mutation
        self.capacity_repair = repair
        self.oversample = oversample

    def do(
        self,
        problem: PlacementProblem,
        pop: Any,
        n_offsprings: int,
        random_state: Any = None,
        n_max_iterations: int | None = None,
        **kwargs: Any,
    ) -> Any:
        rng: np.random.Generator = random_state
        rounds_max = self.n_max_iterations if n_max_iterations is None else n_max_iterations
        genes = genes_of(pop)
        cv, F, crowding = tournament_inputs(pop)  # read once per generation
        seen = {row.tobytes() for row in genes}
        made: list[I64] = []
        rounds = 0
        while len(made) < n_offsprings:
            missing = n_offsprings - len(made)
            children = self._children(problem, genes, cv, F, crowding, missing, rng)
            fresh = []
            for row in children:
                key = row.tobytes()
                if key not in seen:
                    seen.add(key)
                    fresh.append(row)
            made += fresh[:missing]
            rounds += 1
            if rounds >= rounds_max:
                break
        X = np.array(made, dtype=np.int64).reshape(len(made), genes.shape[1])
        return Population.new("X", X)

    def _children(
        self,
        problem: PlacementProblem,
        genes: I64,
        cv: NDArray[np.float64],
        F: NDArray[np.float64],
        crowding: NDArray[np.float64],
        missing: int,
        rng: np.random.Generator,
    ) -> I64:
        """One round: ``missing * oversample`` repaired children (rounded up to pairs), drawn
        as pymoo's ``Mating`` and ``TournamentSelection`` draw them."""
        n_matings = math.ceil(math.ceil(missing * self.oversample) / 2)
        n_random = n_matings * 2 * TOURNAMENT_PRESSURE
        n_perms = math.ceil(n_random / len(genes))
        P = random_permutations(n_perms, len(genes), random_state=rng)[:n_random]
        P = np.reshape(P, (n_matings * 2, TOURNAMENT_PRESSURE))
        parents = tournament(cv, F, crowding, P, rng).reshape(n_matings, 2)
        X = np.swapaxes(genes[parents], 0, 1)  # (2, matings, G)
        cross = rng.random(n_matings) < get(self.crossover.prob, size=n_matings)
        children = X.copy()
        if cross.any():
            crossed = self.crossover._do(problem, X, random_state=rng)
            children[:, cross] = crossed[:, cross]
        children = children.reshape(-1, X.shape[-1])
        mutated = self.mutation._do(problem, children, random_state=rng)
        mut = rng.random(len(children)) <= get(self.mutation.prob, size=len(children))
        children[mut] = mutated[mut]
        if self.capacity_repair is not None:
            children = self.capacity_repair._do(problem, children)
        return np.asarray(children, dtype=np.int64)
