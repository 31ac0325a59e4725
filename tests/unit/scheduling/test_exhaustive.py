"""Tiny search spaces are enumerated: the front is exact and no time goes to pymoo's mating."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.scheduling import plan
from fogfleet.scheduling.objectives import constraints, evaluate

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
