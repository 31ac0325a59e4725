"""Tiny search spaces are enumerated: the front is exact and no time goes to pymoo's mating."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.scheduling import plan
from fogfleet.scheduling.objectives import constraints, evaluate
from fogfleet.scheduling.solver import every_choice

ROOT = Path(__file__).resolve().parents[3]


def test_a_tiny_fleet_is_enumerated_and_its_choice_is_the_exact_lexicographic_optimum() -> None:
    cat = load_paths([ROOT / "manifests/examples/shared-detector"])
    p = build_problem(cat.fleets[0], cat)
    s = plan(p, cat.fleets[0].spec.scheduler)
    assert s.feasible
    assert "enumerated" in s.choice_reason
    # brute force over the same gene spaces
    genes = [np.flatnonzero(p.allowed[i]) for i in range(p.n_instances)]
    grid = np.stack([a.ravel() for a in np.meshgrid(*genes, indexing="ij")], axis=1)
    ok = (constraints(p, grid, p.limits) <= 1e-9).all(axis=1)
    best = evaluate(p, grid[ok], p.limits, ("missRate",))["missRate"].min()
    assert s.objectives["missRate"] <= best + 1e-12
    assert s.evaluations == len(grid)


def test_every_choice_is_meshgrids_product_in_its_order() -> None:
    table = np.array([[3, 5, 0], [1, 0, 0], [2, 4, 6]], dtype=np.int64)
    counts = np.array([2, 1, 3], dtype=np.int64)
    axes = [table[g, : counts[g]] for g in range(3)]
    want = np.stack([a.ravel() for a in np.meshgrid(*axes, indexing="ij")], axis=1)
    assert np.array_equal(every_choice(table, counts), want)


def test_every_choice_takes_more_genes_than_numpy_broadcasts() -> None:
    """40 instances with one node left each (a cluster cut off): one plan, not numpy's
    32-array limit."""
    table = np.arange(40, dtype=np.int64).reshape(40, 1)
    out = every_choice(table, np.ones(40, dtype=np.int64))
    assert out.tolist() == [list(range(40))]
