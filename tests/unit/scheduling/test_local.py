"""Pareto local search: incremental move scores, feasibility, dominance, determinism."""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.choice import dominance
from fogfleet.scheduling.local import MoveEvaluator, pareto_local_search
from fogfleet.scheduling.objectives import EVALUATORS, Evaluation, constraints, evaluate
from fogfleet.scheduling.problem import PlacementProblem, allowed_table
from fogfleet.scheduling.solver import nsga2

from .conftest import _warehouse

NAMES = ("missRate", "missedCycles", "onboard", "reserve", "balance")


def _random_moves(
    me: MoveEvaluator, fulls: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n random one-gene moves (parent, instance, new node) within the gene spaces."""
    k = rng.integers(0, len(me.pair_inst), n)
    par = rng.integers(0, len(fulls), n)
    inst, node = me.pair_inst[k], me.pair_node[k]
    keep = node != fulls[par, inst]
    return par[keep], inst[keep], node[keep]


@settings(max_examples=15, deadline=None)
@given(st.integers(min_value=0, max_value=2**32 - 1), st.booleans())
def test_incremental_scores_equal_whole_plan_evaluation(seed: int, with_limits: bool) -> None:
    """Every objective and constraint of a moved plan, from the parent's per-node sums, is
    what ``objectives.evaluate`` computes for the whole moved plan. Random (mostly
    infeasible) parents; with the nominal allocation nodes are contended, which exercises
    the whole-plan fallback for missRate and missedCycles."""
    rng = np.random.default_rng(seed)
    p = _warehouse()
    # a fleet that runs somewhere already (random nodes, some instances new): migrations count
    placed = PlacementProblem(p, ("missRate",), with_limits=True).full(
        PlacementProblem(p, ("missRate",), with_limits=True).random_genes(1, rng)
    )[0]
    p = dataclasses.replace(p, current=np.where(rng.random(len(placed)) < 0.8, placed, -1))
    pp = PlacementProblem(p, tuple(EVALUATORS), with_limits=with_limits)
    me = MoveEvaluator(pp)
    fulls = pp.full(pp.random_genes(12, rng))
    par, inst, node = _random_moves(me, fulls, 300, rng)
    vals, G = me.evaluate(fulls, par, inst, node)
    kids = me.children(fulls, par, inst, node)
    ref = evaluate(p, kids, pp.alloc)
    for name in EVALUATORS:
        np.testing.assert_allclose(vals[name], ref[name], rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(G, constraints(p, kids, pp.alloc), rtol=0, atol=1e-9)


def test_nominal_parents_are_contended_so_the_fallback_is_tested() -> None:
    p = _warehouse()
    pp = PlacementProblem(p, NAMES, with_limits=False)
    fulls = pp.full(pp.random_genes(12, np.random.default_rng(0)))
    ev = Evaluation(p, fulls, pp.alloc)
    assert (ev.cpu_peak > p.capacity[None, :, 0] * (1 + 1e-9)).any()


def test_incremental_scores_on_tiny_fleet_with_an_overloaded_robot(tiny: Problem) -> None:
    pp = PlacementProblem(tiny, tuple(EVALUATORS))
    me = MoveEvaluator(pp)
    fulls = np.array([[0, 0, 0], [0, 1, 2], [0, 1, 1]])
    par = np.array([0, 0, 0, 1, 1, 2, 2])
    inst = np.array([1, 2, 2, 1, 2, 1, 2])
    node = np.array([1, 1, 2, 0, 0, 2, 0])
    vals, G = me.evaluate(fulls, par, inst, node)
    kids = me.children(fulls, par, inst, node)
    ref = evaluate(tiny, kids, tiny.limits)
    for name in EVALUATORS:
        np.testing.assert_allclose(vals[name], ref[name], rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(G, constraints(tiny, kids, tiny.limits), rtol=0, atol=1e-12)


def test_a_move_must_change_the_node(tiny: Problem) -> None:
    me = MoveEvaluator(PlacementProblem(tiny, NAMES))
    with pytest.raises(ValueError):
        me.evaluate(np.array([[0, 1, 2]]), np.array([0]), np.array([1]), np.array([1]))


@lru_cache(maxsize=1)
def _archive() -> tuple[PlacementProblem, np.ndarray, np.ndarray]:
    """A feasible non-dominated front of a short NSGA-II run without local search."""
    p = _warehouse()
    settings = SchedulerSettings(seed=3, population=40, generations=15, objectives=list(NAMES))
    s = nsga2(p, settings, local_search=False)
    assert s.feasible and s.pareto_placements is not None and s.pareto_front is not None
    pp = PlacementProblem(p, NAMES)
    return pp, s.pareto_placements[:, pp.genes], s.pareto_front


def test_moves_stay_within_allowed_sets_and_are_feasible() -> None:
    pp, X, _ = _archive()
    me = MoveEvaluator(pp)
    fulls = pp.full(X)
    par, inst, node = me.moves(fulls, me.parents(fulls), 10**9)
    assert len(par) > 0
    assert pp.fleet.allowed[inst, node].all()
    assert np.all(node != fulls[par, inst])
    kids = me.children(fulls, par, inst, node)
    assert np.all(constraints(pp.fleet, kids, pp.alloc) <= 1e-9)


def test_local_search_front_is_feasible_inside_gene_spaces_and_scored_right() -> None:
    pp, X, F = _archive()
    nX, nF, n = pareto_local_search(pp, X, F)
    assert n > 0
    full = pp.full(nX)
    assert pp.fleet.allowed[np.arange(pp.fleet.n_instances)[None, :], full].all()
    assert np.all(constraints(pp.fleet, full, pp.alloc) <= 1e-9)
    np.testing.assert_allclose(nF, pp.quantise(pp.objectives_of(nX)), rtol=0, atol=1e-9)


def test_local_search_front_is_never_dominated_by_the_input_front() -> None:
    pp, X, F = _archive()
    _, nF, _ = pareto_local_search(pp, X, F)
    assert not dominance(nF, F).any()  # no input plan dominates a returned one
    assert dominance(F, nF, strict=False).all()  # every input plan is matched or improved
    assert not dominance(nF, nF).any()  # the returned front is mutually non-dominated
    assert len({tuple(r) for r in nF.tolist()}) == len(nF)


def test_local_search_improves_the_archive() -> None:
    pp, X, F = _archive()
    _, nF, _ = pareto_local_search(pp, X, F)
    assert dominance(F, nF).any()  # at least one input plan was strictly improved on


def test_local_search_respects_its_move_budget() -> None:
    pp, X, F = _archive()
    _, nF, n = pareto_local_search(pp, X, F, max_moves=50)
    assert n <= 50
    assert not dominance(nF, F).any()


def test_local_search_is_deterministic() -> None:
    pp, X, F = _archive()
    a = pareto_local_search(pp, X, F)
    b = pareto_local_search(pp, X.copy(), F.copy())
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]


@settings(max_examples=200, deadline=None)
@given(
    st.integers(1, 25).flatmap(
        lambda n: st.integers(1, 30).flatmap(
            lambda m: st.lists(
                st.lists(st.booleans(), min_size=m, max_size=m).filter(any),
                min_size=n,
                max_size=n,
            )
        )
    )
)
@pytest.mark.integration
def test_the_gene_table_is_the_stable_argsort_of_the_allowed_sets(rows: list[list[bool]]) -> None:
    allowed = np.array(rows, dtype=bool)
    counts = allowed.sum(axis=1)
    width = int(counts.max())
    want = np.argsort(~allowed, axis=1, kind="stable")[:, :width]
    assert np.array_equal(allowed_table(allowed, counts, width), want)


def test_the_uncontended_terms_are_looked_up_per_pair_and_zero_outside() -> None:
    pp = PlacementProblem(_warehouse(), ["missRate", "missedCycles"])
    me = MoveEvaluator(pp)
    i, j = me.pair_inst, me.pair_node
    dense = np.zeros((pp.fleet.n_instances, pp.fleet.n_nodes))
    dense[i, j] = me._pair_values(me._miss, i, j)
    assert np.count_nonzero(dense) > 0
    # every (instance, node) cell: the pair's value, or 0 where the search cannot go
    ii, jj = np.indices(dense.shape)
    assert np.array_equal(me._pair_values(me._miss, ii.ravel(), jj.ravel()), dense.ravel())
    outside = ~pp.fleet.allowed
    assert outside.any() and np.all(dense[outside] == 0)
