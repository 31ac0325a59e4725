"""Repair, mutation, crossover and sampling keep plans inside their gene spaces."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.objectives import UPLINK_SHARE, Evaluation, constraints
from fogfleet.scheduling.operators import (
    FleetSampling,
    GeneCrossover,
    GeneMutation,
    repair_plans,
    seed_plans,
    warm_population,
)
from fogfleet.scheduling.problem import PlacementProblem

from .conftest import _warehouse


def _pp() -> PlacementProblem:
    return PlacementProblem(_warehouse(), ("missRate", "reserve"))


def _inside(pp: PlacementProblem, X: np.ndarray) -> bool:
    full = pp.full(X)
    return bool(pp.fleet.allowed[np.arange(pp.fleet.n_instances)[None, :], full].all())


@settings(max_examples=25, deadline=None)
@given(st.integers(min_value=0, max_value=2**32 - 1))
def test_repair_keeps_capacity_where_it_held_and_never_adds_violation(seed: int) -> None:
    pp = _pp()
    rng = np.random.default_rng(seed)
    full = pp.full(pp.random_genes(20, rng))
    before = constraints(pp.fleet, full, pp.alloc)
    fixed = repair_plans(pp, full.copy())
    after = constraints(pp.fleet, fixed, pp.alloc)
    assert np.all(after[before <= 1e-9] <= 1e-9)  # nothing that fitted is overloaded now
    assert np.all(np.maximum(after, 0).sum(axis=1) <= np.maximum(before, 0).sum(axis=1) + 1e-9)
    assert _inside(pp, fixed[:, pp.genes])


def _stuck(pp: PlacementProblem, x: np.ndarray) -> bool:
    """No instance on an overloaded node of plan x (I) can move to another allowed node
    that has room for it (and, if it leaves its robot, uplink to spare)."""
    p, f = pp.fleet, pp.fit
    ev = Evaluation(p, x[None, :], pp.alloc)
    used = np.stack([ev.cpu_requested[0], ev.mem_requested[0], ev.gpu_requested[0]], axis=1)
    over = np.any(used > f.cap + 1e-9, axis=1)
    for i in np.flatnonzero((x >= 0) & over[np.where(x >= 0, x, 0)]):
        h = int(p.home[i])
        for j in np.flatnonzero(p.allowed[i]):
            if j == x[i] or np.any(used[j] + f.demand[i, j] > f.cap[j] + 1e-9):
                continue
            leaves = h >= 0 and x[i] == h
            if leaves and ev.offboard_traffic[0, h] + p.traffic[i] > f.uplink[h] + 1e-9:
                continue
            return False
    return True


def test_repair_makes_every_random_plan_feasible_when_a_node_has_room_for_all() -> None:
    """By construction every random plan is repairable by single moves: edge-1 can host
    every instance at once and the uplinks carry all traffic, so each instance on an
    overloaded node finds room (the pinned ones fit their robot, as the warehouse is
    feasible)."""
    p = _warehouse()
    big = next(k for k, nd in enumerate(p.nodes) if nd.name == "edge-1")
    pinned = p.allowed.sum(axis=1) == 1
    assert np.all(p.allowed[:, big] | pinned)
    cap = p.capacity.copy()
    cap[big, 0] = np.where(p.allowed[:, big], p.limits.cpu_request[:, big], 0.0).sum()
    cap[big, 1] = p.memory.sum()
    uplink = np.full(p.n_nodes, 10 * p.traffic.sum() / UPLINK_SHARE)
    roomy = replace(p, capacity=cap, uplink_bandwidth=uplink)
    pp = PlacementProblem(roomy, ("missRate", "reserve"))
    full = pp.full(pp.random_genes(500, np.random.default_rng(0)))
    assert (constraints(roomy, full, pp.alloc).max(axis=1) > 0).mean() > 0.5
    fixed = repair_plans(pp, full)
    assert np.all(constraints(roomy, fixed, pp.alloc) <= 1e-9)


def test_repair_leaves_a_warehouse_plan_infeasible_only_when_no_single_move_fits() -> None:
    """On the re-calibrated warehouse 4-core instances fill 7.5-core edges: a random plan
    can leave the free cores fragmented (3.5 here, 3.5 there), and the repair, which moves
    one instance at a time to a node with room and never swaps, then stops. The right
    property is that it stops only there: every plan it leaves infeasible has no instance
    on an overloaded node that could move to an allowed node with room. The share it fixes
    (0.936 on these 500 plans; 0.98 before the re-calibration) is checked against 0.9 only
    as a guard against a regression of the repair itself."""
    pp = _pp()
    full = pp.full(pp.random_genes(500, np.random.default_rng(0)))
    assert (constraints(pp.fleet, full, pp.alloc).max(axis=1) > 0).mean() > 0.9
    fixed = repair_plans(pp, full)
    feasible = constraints(pp.fleet, fixed, pp.alloc).max(axis=1) <= 1e-9
    assert feasible.mean() >= 0.9
    assert all(_stuck(pp, fixed[r]) for r in np.flatnonzero(~feasible))


def test_overloaded_node_is_repaired_by_moving_off_it(tiny: Problem) -> None:
    pp = PlacementProblem(tiny, ("missRate",))
    x = np.array([[0, 0, 0]])  # 3 cores requested on a 2-core robot
    fixed = repair_plans(pp, x.copy())
    assert fixed[0, 0] == 0  # pinned instance stays
    assert np.all(constraints(tiny, fixed, tiny.limits) <= 1e-9)
    assert (fixed[0] != 0).sum() == 1  # one move is enough


def test_feasible_plans_are_left_alone(tiny: Problem) -> None:
    pp = PlacementProblem(tiny, ("missRate",))
    x = np.array([[0, 0, 2]])
    assert np.array_equal(repair_plans(pp, x.copy()), x)


def test_mutation_stays_within_allowed_sets() -> None:
    pp = _pp()
    rng = np.random.default_rng(3)
    X = pp.random_genes(50, rng)
    Y = GeneMutation(prob=1.0, per_gene=0.5)._do(pp, X, random_state=rng)
    assert _inside(pp, Y)
    assert (Y != X).any()


def test_mutation_changes_at_least_one_gene_draw_per_plan() -> None:
    pp = _pp()
    rng = np.random.default_rng(4)
    X = pp.random_genes(200, rng)
    Y = GeneMutation(prob=1.0)._do(pp, X, random_state=np.random.default_rng(5))
    changed = (Y != X).sum(axis=1)
    assert changed.max() <= 6 and changed.mean() > 0.5


def test_crossover_children_take_each_gene_from_a_parent() -> None:
    pp = _pp()
    rng = np.random.default_rng(6)
    a, b = pp.random_genes(10, rng), pp.random_genes(10, rng)
    for kind in ("uniform", "single_point"):
        kids = GeneCrossover(kind)._do(pp, np.stack([a, b]), random_state=np.random.default_rng(7))
        assert kids.shape == (2, 10, pp.n_var)
        assert np.all((kids[0] == a) | (kids[0] == b))
        assert np.all((kids[0] == a) == (kids[1] == b))


def test_sampling_starts_with_current_placement(warehouse: Problem) -> None:
    current = np.where(warehouse.home >= 0, warehouse.home, 0).astype(np.int64)
    p = replace(warehouse, current=current)
    pp = PlacementProblem(p, ("missRate",))
    X = FleetSampling()._do(pp, 10, random_state=np.random.default_rng(1))
    assert np.array_equal(X[0], current[pp.genes])
    assert _inside(pp, X)
    assert len(seed_plans(pp)) >= 3


def test_warm_population_redraws_a_few_genes_of_the_seeds_inside_their_gene_spaces() -> None:
    pp = _pp()
    seeds = np.stack([p[pp.genes] for p in seed_plans(pp)])
    rng = np.random.default_rng(3)
    X = warm_population(pp, seeds, 40, rng, share=0.05)
    assert X.shape == (40, pp.n_var)
    assert _inside(pp, X)
    base = seeds[np.arange(40) % len(seeds)]
    changed = (base != X).sum(axis=1)
    # at least one gene is re-drawn (it may land on the node it had), never most of them
    assert changed.max() <= pp.n_var // 4
    assert (changed > 0).mean() > 0.5


def test_fleet_sampling_warm_starts_large_fleets_only(monkeypatch: pytest.MonkeyPatch) -> None:
    pp = _pp()
    k = len(seed_plans(pp))
    cold = FleetSampling()._do(pp, 30, random_state=np.random.default_rng(5))
    monkeypatch.setattr("fogfleet.scheduling.operators.WARM_START_GENES", pp.n_var)
    warm = FleetSampling()._do(pp, 30, random_state=np.random.default_rng(5))
    # the seed plans come first, repaired: within capacity and uplinks
    assert (constraints(pp.fleet, pp.full(warm[:k]), pp.alloc) <= 1e-9).all()

    def near(X: np.ndarray) -> np.ndarray:
        return (X[k:, None, :] != warm[None, :k]).sum(axis=2).min(axis=1)

    # the warm individuals stay near a seed; uniform random ones do not
    assert near(warm).max() < near(cold).min()
