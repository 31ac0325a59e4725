"""pymoo's bookkeeping on gene arrays (``bookkeeping``, ``mating``): the same evolution as
pymoo's defaults, only cheaper."""

from __future__ import annotations

import numpy as np
import pytest
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.evaluator import Evaluator
from pymoo.core.population import Population
from pymoo.operators.selection.tournament import TournamentSelection

from fogfleet.scheduling.bookkeeping import (
    ArrayEvaluator,
    FleetNSGA2,
    GeneDuplicates,
    RankAndCrowdingSurvival,
    binary_tournament,
)
from fogfleet.scheduling.mating import ArrayMating
from fogfleet.scheduling.operators import (
    CapacityRepair,
    FleetSampling,
    GeneCrossover,
    GeneMutation,
)
from fogfleet.scheduling.problem import PlacementProblem

from .conftest import _warehouse


def _run(mating: str, generations: int = 15, *, arrays: bool = False) -> NSGA2:
    pp = PlacementProblem(_warehouse(), ("missRate", "onboard", "reserve", "balance"))
    crossover, mutation, repair = GeneCrossover("uniform"), GeneMutation(prob=0.3), CapacityRepair()
    algo = (FleetNSGA2 if arrays else NSGA2)(
        pop_size=40,
        sampling=FleetSampling(),
        crossover=crossover,
        mutation=mutation,
        repair=repair,
        eliminate_duplicates=GeneDuplicates(),
        survival=RankAndCrowdingSurvival(),
        selection=TournamentSelection(func_comp=binary_tournament),
        mating={
            "pymoo": None,
            "array": ArrayMating(crossover, mutation, repair, oversample=1.0),
            "oversampled": ArrayMating(crossover, mutation, repair, oversample=1.5),
        }[mating],
        evaluator=ArrayEvaluator() if arrays else None,
    )
    algo.setup(pp, termination=("n_gen", generations), seed=7, verbose=False)
    while algo.has_next():
        algo.next()
    return algo


def test_at_oversample_one_it_draws_what_pymoos_mating_draws() -> None:
    """Same seed, same populations generation after generation: the arrays only save the
    bookkeeping (and the evaluator the per-individual CV). A change in the order of any draw
    (tournament permutations, ties, the crossover or mutation mask) would give other
    offspring within a generation or two."""
    a, b = _run("pymoo"), _run("array", arrays=True)
    assert np.array_equal(a.pop.get("X"), b.pop.get("X"))
    assert np.array_equal(a.pop.get("F"), b.pop.get("F"))
    assert a.evaluator.n_eval == b.evaluator.n_eval
    assert np.array_equal(a.opt.get("X"), b.opt.get("X"))  # FleetNSGA2's optimum: pymoo's


def test_offspring_are_unique_repaired_and_new() -> None:
    """Every offspring is new (not a parent, not another offspring), inside its gene space
    and capacity-feasible after the repair; there are as many as asked for."""
    algo = _run("oversampled", generations=3)
    pp, pop = algo.problem, algo.pop
    mating = algo.mating
    off = mating.do(pp, pop, 40, random_state=np.random.default_rng(3), algorithm=algo)
    X = off.get("X").astype(np.int64)
    assert X.shape == (40, pp.n_var)
    parents = {row.tobytes() for row in pop.get("X").astype(np.int64)}
    keys = [row.tobytes() for row in X]
    assert len(set(keys)) == len(keys) and not set(keys) & parents
    full = pp.full(X)
    assert pp.fleet.allowed[np.arange(pp.fleet.n_instances)[None, :], full].all()
    out: dict[str, np.ndarray] = {}
    pp._evaluate(X, out)
    assert (out["G"] <= 1e-9).all(), "the warehouse has room: every repaired plan fits"


def test_it_stops_after_its_rounds_when_no_new_offspring_can_be_made() -> None:
    """A population of one plan with one gene value each has no new child: pymoo's rule
    (give up after ``n_max_iterations`` rounds) instead of spinning."""
    pp = PlacementProblem(_warehouse(), ("missRate",))
    only = pp.table[:, 0][None, :]
    pp.counts = np.ones_like(pp.counts)  # every gene has one value: no child differs
    pop = Population.new("X", only)
    pop.set("F", np.zeros((1, 1)), "CV", np.zeros((1, 1)))
    mating = ArrayMating(GeneCrossover(), GeneMutation(prob=1.0), None, n_max_iterations=5)
    off = mating.do(pp, pop, 10, random_state=np.random.default_rng(0))
    assert len(off) == 0


def test_oversample_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="oversample must be at least 1"):
        ArrayMating(GeneCrossover(), GeneMutation(), None, oversample=0.5)


def test_cheaper_pymoo_bookkeeping_gives_the_same_run() -> None:
    """GeneDuplicates, RankAndCrowdingSurvival and the vectorised binary_tournament replace
    pymoo's defaults only to save time: the same seed must give the same populations."""

    def run(fast: bool) -> tuple[np.ndarray, np.ndarray]:
        pp = PlacementProblem(_warehouse(), ("missRate", "onboard", "reserve"))
        extra = (
            {
                "eliminate_duplicates": GeneDuplicates(),
                "survival": RankAndCrowdingSurvival(),
                "selection": TournamentSelection(func_comp=binary_tournament),
            }
            if fast
            else {"eliminate_duplicates": True}
        )
        algo = NSGA2(
            pop_size=30,
            sampling=FleetSampling(),
            crossover=GeneCrossover("uniform"),
            mutation=GeneMutation(prob=0.3),
            repair=CapacityRepair(),
            **extra,
        )
        algo.setup(pp, termination=("n_gen", 12), seed=5, verbose=False)
        while algo.has_next():
            algo.next()
        return algo.pop.get("X"), algo.pop.get("F")

    (xa, fa), (xb, fb) = run(False), run(True)
    assert np.array_equal(xa, xb)
    assert np.array_equal(fa, fb)


def test_the_array_evaluator_sets_what_pymoos_evaluator_sets() -> None:
    """F, G and the constraint violation of unrepaired random plans (most over capacity,
    several constraints violated at once) match pymoo's lazily computed CV exactly."""
    pp = PlacementProblem(_warehouse(), ("missRate", "onboard", "reserve"))
    X = pp.random_genes(60, np.random.default_rng(11))
    ours, theirs = Population.new("X", X), Population.new("X", X.copy())
    ArrayEvaluator().eval(pp, ours)
    Evaluator().eval(pp, theirs)
    cv = theirs.get("CV")
    assert (cv > 0).sum() > 10 and (np.asarray(theirs.get("G")) > 0).sum(axis=1).max() > 1
    assert np.array_equal(ours.get("F"), theirs.get("F"))
    assert np.array_equal(ours.get("G"), theirs.get("G"))
    assert np.array_equal(ours.get("CV"), cv)
    assert np.array_equal(ours.get("FEAS"), theirs.get("FEAS"))
