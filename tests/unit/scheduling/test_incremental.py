"""Incremental re-planning: only what a change affected (plus a small neighbourhood) moves."""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import Catalog, load_paths
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerSettings
from fogfleet.bench.scheduling import synthetic_fleet
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem, freeze
from fogfleet.scheduling import incremental
from fogfleet.scheduling.decision import CorePlanner, decide, fingerprint
from fogfleet.scheduling.heuristics import Fit
from fogfleet.scheduling.incremental import changed_instances, replan
from fogfleet.scheduling.solver import plan
from fogfleet.scheduling.stickiness import feasible, fill_around, mask_unavailable

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
ROBOTS, EDGES = 20, 8
SETTINGS = SchedulerSettings(seed=1, population=20, generations=10)


@lru_cache(maxsize=1)
def _fleet() -> tuple[Catalog, RobotFleet]:
    return synthetic_fleet(ROBOTS + 1, EDGES, 3)


def _without_last_robot() -> RobotFleet:
    _, fleet = _fleet()
    spec = fleet.spec.model_copy(update={"robots": fleet.spec.robots[:ROBOTS]})
    return fleet.model_copy(update={"spec": spec})


@lru_cache(maxsize=1)
def _running() -> tuple[Problem, np.ndarray]:
    """The fleet of ROBOTS robots and its planned placement."""
    cat, _ = _fleet()
    p0 = build_problem(_without_last_robot(), cat)
    s0 = plan(p0, SETTINGS)
    assert s0.feasible
    return p0, s0.placement


def _current(p0: Problem, x: np.ndarray) -> dict[tuple[str, str, int], str]:
    return {
        (inst.robot, inst.module, inst.replica): p0.nodes[j].node_name
        for inst, j in zip(p0.instances, x, strict=True)
    }


def _joined() -> Problem:
    """One robot more, the others running where they were planned."""
    cat, fleet = _fleet()
    p0, x = _running()
    return build_problem(fleet, cat, _current(p0, x))


def _unchanged_rerun() -> Problem:
    cat, _ = _fleet()
    p0, x = _running()
    return build_problem(_without_last_robot(), cat, _current(p0, x))


def _budget(problem: Problem, affected: int) -> int:
    placed = int((problem.current >= 0).sum())
    return math.ceil(incremental.NEIGHBOURHOOD_SHARE * (placed - affected))


def test_a_joining_robot_frees_its_instances_and_a_small_neighbourhood() -> None:
    p1 = _joined()
    new = p1.current < 0
    assert new.sum() == 8
    out = replan(p1, SETTINGS)
    assert out.schedule is not None, out.reason
    x = out.schedule.placement
    assert out.schedule.feasible and feasible(p1, x)
    assert (x[new] >= 0).all()
    assert out.affected == 8
    assert out.freed - out.affected <= _budget(p1, 8)
    moved = (~new) & (x != p1.current)
    assert moved.sum() <= out.freed - out.affected
    assert "incremental re-plan" in out.schedule.choice_reason


def test_the_neighbourhood_follows_regret_siblings_and_crowding() -> None:
    """The neighbour picked first is the instance furthest from its best node."""
    p1 = _joined()
    from fogfleet.scheduling.heuristics import Fit

    fit = Fit(p1, p1.limits)
    kept = np.where(p1.current >= 0, p1.current, -1)
    x = kept.copy()
    # put one running instance on its worst allowed node: the largest regret of the fleet
    spread = np.where(
        kept >= 0,
        np.where(p1.allowed, fit.q, -1.0).max(axis=1) - fit.q.min(axis=1),
        -1.0,
    )
    i = int(np.argmax(spread))
    worst = int(np.argmax(np.where(p1.allowed[i], fit.q[i], -1.0)))
    assert fit.q[i, worst] - fit.q[i].min() > 1e-3
    x[i] = worst
    out = incremental._neighbourhood(p1, fit, x, p1.current < 0)
    assert out[i]
    assert out.sum() == _budget(p1, 8)
    assert not out[p1.current < 0].any()


def test_nothing_running_asks_for_a_full_plan() -> None:
    p1 = _joined()
    fresh = dataclasses.replace(p1, current=freeze(np.full(p1.n_instances, -1)))
    out = replan(fresh, SETTINGS)
    assert out.schedule is None and out.reason == "nothing runs yet"


def test_a_change_beyond_the_affected_share_asks_for_a_full_plan() -> None:
    p1 = _joined()
    changed = range(int(incremental.MAX_AFFECTED_SHARE * p1.n_instances) + 1)
    out = replan(p1, SETTINGS, changed=changed)
    assert out.schedule is None and "more than 10%" in out.reason


def test_a_result_worse_than_the_deployed_plan_asks_for_a_full_plan() -> None:
    p1 = _joined()
    out = replan(p1, SETTINGS, reference=-1.0)
    assert out.schedule is None and "worse than the deployed" in out.reason
    assert replan(p1, SETTINGS, reference=1.0).schedule is not None


def test_a_failed_node_moves_only_its_instances_and_the_neighbourhood() -> None:
    _, x = _running()
    p = _unchanged_rerun()
    count = np.bincount(x, minlength=p.n_nodes)
    edges = [j for j in range(p.n_nodes) if p.tier[j] == 1 and count[j] > 0]
    down = min(edges, key=lambda j: count[j])  # within the affected share
    masked, stranded = mask_unavailable(p, {down: "NotReady"})
    assert not stranded
    # the synthetic fleet's edges are full: give the others room for what ran on ``down``
    cap = masked.capacity.copy()
    cap[masked.tier == 1] *= 1.5
    masked = dataclasses.replace(masked, capacity=freeze(cap))
    on_it = x == down
    # losing a node narrows many gene spaces: that alone changes no instance
    assert changed_instances(p, masked) == set()
    out = replan(masked, SETTINGS)
    assert out.schedule is not None, out.reason
    y = out.schedule.placement
    assert out.affected == on_it.sum()
    assert not (y == down).any()
    moved_others = (~on_it) & (y != x)
    assert moved_others.sum() <= out.freed - out.affected


def test_a_shrunk_node_releases_what_no_longer_fits() -> None:
    _, x = _running()
    p = _unchanged_rerun()
    j = int(np.bincount(x[p.tier[x] == 1], minlength=p.n_nodes).argmax())
    cap = p.capacity.copy()
    cap[j, 0] = 0.5 * cap[j, 0]
    shrunk = dataclasses.replace(p, capacity=freeze(cap))
    out = replan(shrunk, SETTINGS)
    assert out.schedule is not None, out.reason
    assert out.affected > 0
    assert feasible(shrunk, out.schedule.placement)


def test_changed_instances_names_only_the_changed_module() -> None:
    cat, _ = _fleet()
    p0, x = _running()
    assert changed_instances(p0, _unchanged_rerun()) == set()
    assert changed_instances(p0, _joined()) == set(), "a new robot's instances are new, not changed"
    module = p0.module_names[0]
    key = next(k for k in cat.modules if k[1] == module)
    old = cat.modules[key]
    spec = old.spec.model_copy(update={"cycle_time_millis": 2 * float(old.spec.cycle_time_millis)})
    cat2 = Catalog(
        nodes=dict(cat.nodes), modules={**cat.modules, key: old.model_copy(update={"spec": spec})}
    )
    p2 = build_problem(_without_last_robot(), cat2, _current(p0, x))
    want = {i for i, inst in enumerate(p2.instances) if inst.module == module}
    assert changed_instances(p0, p2) == want


def test_changed_instances_finds_one_changed_cell_by_views_and_by_copies(monkeypatch) -> None:
    """One instance's CPU request on one node, in a fleet a robot joined (rows and columns
    shifted): the block-wise comparison and the gathered one both find exactly it."""
    p0, _ = _running()
    p1 = _joined()
    old_rows = {inst: k for k, inst in enumerate(p0.instances)}
    old_cols = {n.name for n in p0.nodes}
    i, j = next(
        (i, j)
        for i, inst in reversed(list(enumerate(p1.instances)))
        if inst in old_rows
        for j in reversed(range(p1.n_nodes))
        if p1.allowed[i, j] and p1.nodes[j].name in old_cols
    )
    cpu = p1.limits.cpu_request.copy()
    cpu[i, j] *= 2
    edited = dataclasses.replace(p1, limits=dataclasses.replace(p1.limits, cpu_request=freeze(cpu)))
    assert changed_instances(p0, edited) == {i}
    monkeypatch.setattr(incremental, "MAX_COMPARED_BLOCKS", 0)
    assert changed_instances(p0, edited) == {i}
    assert changed_instances(p0, p1) == set()


def test_changed_instances_are_re_placed() -> None:
    """A changed instance is free even where it still fits: it may go to a better node."""
    p = _unchanged_rerun()
    out = replan(p, SETTINGS, changed={0, 1})
    assert out.schedule is not None
    assert out.affected == 2


def test_fill_places_the_instances_with_fewest_nodes_first() -> None:
    """Largest-first alone fills the new robot with its big offloadable modules and leaves
    no room for the modules that must run on board."""
    p1 = _joined()
    fixed = np.where(p1.current >= 0, p1.current, -1)
    x = fill_around(p1, fixed, np.full(p1.n_instances, -1))
    assert (x >= 0).all()
    assert feasible(p1, x)


@pytest.mark.parametrize("seed", [1, 2])
def test_the_incremental_plan_is_deterministic(seed: int) -> None:
    p1 = _joined()
    s = SETTINGS.model_copy(update={"seed": seed})
    a, b = replan(p1, s), replan(p1, s)
    assert a.schedule is not None and b.schedule is not None
    assert np.array_equal(a.schedule.placement, b.schedule.placement)


def test_no_room_around_the_others_asks_for_a_full_plan() -> None:
    _, x = _running()
    p = _unchanged_rerun()
    count = np.bincount(x, minlength=p.n_nodes)
    # the busiest edges lose their CPU until more than a tenth of the fleet must move (what
    # the running plan puts where depends on the planner, so count instead of assuming)
    cap = p.capacity.copy()
    lost = 0
    for j in sorted(np.flatnonzero(p.tier == 1), key=lambda j: -count[j]):
        if lost > incremental.MAX_AFFECTED_SHARE * p.n_instances:
            break
        cap[j, 0] = 0.0
        lost += int(count[j])
    starved = dataclasses.replace(p, capacity=freeze(cap))
    out = replan(starved, SETTINGS)
    assert out.schedule is None
    assert "do not fit" in out.reason or "more than 10%" in out.reason


def test_the_best_uncontended_miss_is_the_minimum_over_the_allowed_nodes():
    """``best_uncontended_miss`` skips the robots' computers an instance may not use; its
    values are those of the whole (R, N) table's row minima, also where a robot's computer
    is allowed to another robot's instance (as a node the fleet shares) or nothing is."""
    from fogfleet.scheduling.heuristics import best_uncontended_miss, uncontended_miss

    problem, _ = _running()
    allowed = np.array(problem.allowed)
    robots = np.flatnonzero(problem.tier == 0)
    allowed[0, robots[-1]] = True  # another robot's computer
    allowed[1, :] = False  # nowhere
    allowed[2, :] = False
    allowed[2, robots[-1]] = True  # only a robot's computer
    p = dataclasses.replace(problem, allowed=freeze(allowed))
    rows = np.arange(p.n_instances)
    want = uncontended_miss(p, p.limits, rows).min(axis=1)
    got = best_uncontended_miss(p, p.limits, rows)
    np.testing.assert_array_equal(got, want)
    assert got[1] == 1.0


@pytest.mark.parametrize("cells", [10**12, 290])
def test_the_local_search_scores_at_most_the_move_and_cell_budgets(monkeypatch, cells):
    """A move costs a pass over the nodes: on a cluster of many nodes the search scores at
    most MAX_MOVE_CELLS // nodes moves (here 29 nodes: 290 cells are 10 moves), else at most
    MAX_MOVES."""
    p1 = _joined()
    assert p1.n_nodes == 29
    scored: list[int] = []
    search = incremental.pareto_local_search

    def counting(*args, **kwargs):
        X, F, n = search(*args, **kwargs)
        scored.append(n)
        return X, F, n

    monkeypatch.setattr(incremental, "pareto_local_search", counting)
    monkeypatch.setattr(incremental, "MAX_MOVE_CELLS", cells)
    assert replan(p1, SETTINGS, reference=None).schedule is not None
    (n,) = scored
    if cells == 290:
        assert n == 10  # the cell budget stopped it (without it, it scores more: below)
    else:
        assert 10 < n <= incremental.MAX_MOVES


def test_a_first_decision_for_a_running_fleet_keeps_what_runs(
    warehouse_left_by_edge: Problem,
) -> None:
    # a new leader (no last decision in memory) finds the warehouse running and an edge gone
    # from spec.nodes: on its full edges the whole-fleet plan moved 18 running instances to
    # place the 2 that ran there; around what runs, 4 moves make room (the fewest: below)
    p = warehouse_left_by_edge
    settings = SchedulerSettings()
    fp = fingerprint(p, settings)
    kept = decide(CorePlanner(), p, settings, fleet="w", fp=fp, before=p.current)
    assert kept.incremental and "kept what runs" in kept.choice_reason, kept.choice_reason
    assert feasible(p, kept.placement)
    running = p.current >= 0
    moved = int(np.sum(running & (kept.placement != p.current)))
    assert moved == _fewest_moves(p), kept.moves  # 4 on this plan
    # incremental re-planning off: the whole-fleet plan, as before
    whole = decide(CorePlanner(), p, settings.model_copy(update={"incremental": False}),
                   fleet="w", fp=fp, before=p.current)  # fmt: skip
    assert not whole.incremental
    assert int(np.sum(running & (whole.placement != p.current))) > moved


@pytest.fixture(scope="module")
def warehouse_left_by_edge() -> Problem:
    """The warehouse as planned, then the edge running the fewest instances (2, on full
    edges) taken out of spec.nodes, with everything else running where it was planned."""
    cat = load_paths([WAREHOUSE])
    (fleet,) = cat.fleets
    p0 = build_problem(fleet, cat)
    settings = SchedulerSettings()
    x = decide(CorePlanner(), p0, settings, fleet="w", fp=fingerprint(p0, settings),
               before=np.full(p0.n_instances, -1)).placement  # fmt: skip
    count = {n: int(np.sum(x == j)) for j, n in enumerate(p0.nodes)}
    gone = min((n.name for n in p0.nodes if n.tier.value == "edge" and count[n]),
               key=lambda name: count[next(n for n in p0.nodes if n.name == name)])  # fmt: skip
    spec = fleet.spec.model_copy(update={"nodes": [n for n in fleet.spec.nodes if n != gone]})
    return build_problem(fleet.model_copy(update={"spec": spec}), cat, _current(p0, x))


def _fewest_moves(p: Problem) -> int:
    """The oracle: the fewest running instances any placement of every instance within the
    nodes' CPU, memory and GPUs moves (a MILP over all instances and nodes, uplinks left
    out: a lower bound on what ``room.fewest_moves`` may reach)."""
    import scipy.sparse as sp
    from scipy.optimize import Bounds, LinearConstraint, milp

    fit = Fit(p, p.limits)
    pairs = [(i, j) for i in range(p.n_instances) for j in np.flatnonzero(p.allowed[i])]
    cost = np.array([float(p.current[i] >= 0 and j != p.current[i]) for i, j in pairs])
    rows, cols, vals, ub = [], [], [], []
    placed = sorted({i for i, _ in pairs})
    for r, i in enumerate(placed):
        for k, (a, _) in enumerate(pairs):
            if a == i:
                rows.append(r), cols.append(k), vals.append(1.0)
    lb = [1.0] * len(placed)
    ub = [1.0] * len(placed)
    for j in range(p.n_nodes):
        for res in range(3):
            r = len(lb)
            for k, (a, b) in enumerate(pairs):
                if b == j:
                    rows.append(r), cols.append(k), vals.append(fit.demand[a, j, res])
            lb.append(-np.inf)
            ub.append(fit.cap[j, res] - fit.reserve[j, res])
    a = sp.csr_matrix((vals, (rows, cols)), shape=(len(lb), len(pairs)))
    res = milp(cost, constraints=LinearConstraint(a, lb, ub), integrality=np.ones(len(pairs)),
               bounds=Bounds(0, 1))  # fmt: skip
    assert res.x is not None
    return round(res.fun)


def test_a_fleet_of_which_nothing_runs_gets_the_whole_fleet_plan() -> None:
    cat, _ = _fleet()
    p = build_problem(_without_last_robot(), cat)
    fresh = decide(CorePlanner(), p, SETTINGS, fleet="f", fp=fingerprint(p, SETTINGS),
                   before=np.full(p.n_instances, -1))  # fmt: skip
    assert not fresh.incremental
