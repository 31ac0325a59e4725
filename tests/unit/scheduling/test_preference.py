"""Soft rules of the lexicographic choice (scheduling.preference): preferred tiers, then cost,
after the miss objectives; the chosen plan is polished towards them at no extra miss."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.objectives import constraints, evaluate
from fogfleet.scheduling.preference import polish
from fogfleet.scheduling.solver import plan

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"


def _site(tmp_path: Path, *, price: float, fleet_wish: str = "", module_wish: str = "") -> Problem:
    """The warehouse plus two cloud nodes at ``price`` per core-hour."""
    for f in WAREHOUSE.glob("*.yaml"):
        shutil.copy(f, tmp_path / f.name)
    cloud = "\n".join(
        f"---\napiVersion: fogfleet.io/v1alpha1\nkind: ComputeNode\nmetadata: {{name: cloud-{k}}}\n"
        "spec:\n  tier: cloud\n  hardwareType: dsv3-16\n  capacity: {cpu: 16, memory: 64Gi}\n"
        f"  privacyLevel: 2\n  costPerCoreHour: {price}\n"
        "  network: [{type: wan, latencyMillis: 3, jitterMillis: 0.5, bandwidthMbps: 1000}]"
        for k in (1, 2)
    )
    (tmp_path / "nodes.yaml").write_text((tmp_path / "nodes.yaml").read_text() + "\n" + cloud)
    fleet = (tmp_path / "fleet.yaml").read_text()
    old = "  nodes: [edge-1, edge-2, edge-3, edge-4, edge-5, edge-6]\n"
    assert old in fleet
    new = "  nodes: [edge-1, edge-2, edge-3, edge-4, edge-5, edge-6, cloud-1, cloud-2]\n"
    fleet = fleet.replace(old, (f"  preferredTiers: {fleet_wish}\n" if fleet_wish else "") + new)
    if module_wish:
        fleet = fleet.replace(
            "  - name: nav-motion-planning\n",
            f"  - name: nav-motion-planning\n    overrides: {{preferredTiers: {module_wish}}}\n",
        )
        assert "overrides: {preferredTiers" in fleet
    (tmp_path / "fleet.yaml").write_text(fleet)
    catalog = load_paths([tmp_path])
    return build_problem(catalog.fleets[0], catalog)


def _in_cloud(p: Problem, x: np.ndarray) -> int:
    return int(np.isin(x, np.flatnonzero(p.tier == 2)).sum())


def test_a_free_cloud_is_left_for_overflow_when_the_fleet_prefers_robot_and_edge(
    tmp_path: Path,
) -> None:
    settings = SchedulerSettings(seed=1)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    free = _site(tmp_path / "a", price=0)
    wished = _site(tmp_path / "b", price=0, fleet_wish="[robot, edge]")
    assert free.preferred is None and wished.preferred is not None
    loose, kept = plan(free, settings), plan(wished, settings)
    assert loose.feasible and kept.feasible
    assert "offPreferred" in kept.choice_reason and "offPreferred" not in loose.choice_reason
    assert _in_cloud(wished, kept.placement) < _in_cloud(free, loose.placement)
    misses = ("missRate", "missedCycles")
    a = evaluate(free, loose.placement[None, :], free.limits, misses)
    b = evaluate(wished, kept.placement[None, :], wished.limits, misses)
    for n in misses:  # "miss alike": within the choice's tolerance, once for the choice and
        # once for the polish (1e-6 + 0.1 %)
        assert b[n][0] <= a[n][0] + 2 * (1e-6 + 1e-3 * a[n][0])
    # the polish is at a fixed point: no single move to a preferred node is left
    again, moved = polish(wished, kept.placement, kept.objective_names)
    assert moved == 0 and np.array_equal(again, kept.placement)


def test_polish_moves_work_onto_a_robot_only_its_own_and_keeps_the_plan_feasible(
    tmp_path: Path,
) -> None:
    p = _site(tmp_path, price=0.2)
    s = plan(p, SchedulerSettings(seed=2, generations=20, population=30))
    x, _ = polish(p, s.placement, s.objective_names)
    on_board = p.tier[s.placement] == 0
    assert np.array_equal(x[on_board], s.placement[on_board])  # robots cost nothing: they stay
    to_robot = p.tier[x] == 0
    assert np.array_equal(x[to_robot], p.home[to_robot])  # never another robot's computer
    # onto a robot only for a module whose standby holds its CPU there (no wishes here)
    assert np.all(p.held_at_home[to_robot & ~on_board])
    assert np.all(constraints(p, x[None, :], p.limits) <= 1e-9)


def _robot_edge_cloud(*, preferred: list[bool] | None = None, cloud_price: float = 1.0) -> Problem:
    """A 4-core robot (0), a 4-core edge (1) holding a 3.5-core neighbour of the instance,
    and a 4-core cloud (2) at ``cloud_price``. Instance 1 (1 core) meets its 1 s cycle alike
    everywhere (no transfer, no jitter): only the soft rules tell its nodes apart."""
    from dataclasses import replace

    from .conftest import make_problem

    p = make_problem(
        tiers=[0, 1, 2],
        cpu=[4.0, 4.0, 4.0],
        mem=[8.0, 8.0, 8.0],
        home=[0, 0],
        allowed=[[False, True, False], [True, True, True]],
        activation=[1.0, 1.0],
        cycle=[1.0, 1.0],
        request=[[0.0, 3.5, 0.0], [1.0, 1.0, 1.0]],
        exe=[[0.0, 0.1, 0.0], [0.1, 0.1, 0.1]],
        cost=[0.0, 0.0, cloud_price],
    )
    if preferred is None:
        return p
    return replace(p, preferred=np.array([preferred, preferred], dtype=bool))


def test_a_paid_cloud_instance_moves_back_to_its_robot() -> None:
    """Issue 35: preferredTiers [robot, edge], the edge is full, the robot has room, the
    misses are the same: the move after the choice takes the instance out of the paid cloud
    and back onto its robot."""
    p = _robot_edge_cloud(preferred=[True, True, False], cloud_price=1.0)
    x, moved = polish(p, np.array([1, 2]), ("missRate", "missedCycles", "onboard"))
    assert moved == 1 and x.tolist() == [1, 0]


def test_without_a_wish_for_the_robot_a_cheaper_robot_is_no_target() -> None:
    """No preference and no standby holding the CPU: on-board use is F1's to weigh, so the
    polish (a tie-break on cost) does not fill the robot."""
    p = _robot_edge_cloud(cloud_price=1.0)
    x, moved = polish(p, np.array([1, 2]), ("missRate", "missedCycles", "onboard"))
    assert moved == 0 and x.tolist() == [1, 2]


def test_a_paid_cloud_instance_whose_standby_holds_its_cpu_moves_back_to_its_robot() -> None:
    from dataclasses import replace

    p = replace(_robot_edge_cloud(cloud_price=1.0), fallback=np.array([False, True]))
    x, moved = polish(p, np.array([1, 2]), ("missRate", "missedCycles", "onboard"))
    assert moved == 1 and x.tolist() == [1, 0]


def test_a_fleet_that_prefers_robot_and_edge_leaves_a_free_cloud_for_overflow() -> None:
    """preferredTiers [robot, edge]: a free cloud is still not where the instance belongs
    while its robot can host it at the same misses."""
    p = _robot_edge_cloud(preferred=[True, True, False], cloud_price=0.0)
    x, moved = polish(p, np.array([1, 2]), ("missRate", "missedCycles", "onboard"))
    assert moved == 1 and x.tolist() == [1, 0]


def test_an_instance_leaves_its_robot_when_its_module_prefers_the_edge_and_cloud() -> None:
    p = _robot_edge_cloud(preferred=[False, True, True], cloud_price=0.0)
    x, moved = polish(p, np.array([1, 0]), ("missRate", "missedCycles", "onboard"))
    assert moved == 1 and x.tolist() == [1, 2]  # the edge is full: the cloud


def test_a_fleet_override_of_preferred_tiers_wins_over_the_fleet_default(tmp_path: Path) -> None:
    p = _site(tmp_path, price=0, fleet_wish="[robot, edge]", module_wish="[cloud]")
    assert p.preferred is not None
    for i, inst in enumerate(p.instances):
        tiers = {p.nodes[j].tier.value for j in np.flatnonzero(p.preferred[i])}
        if inst.module == "nav-motion-planning":
            assert tiers == {"cloud"}
        else:
            assert tiers == {"robot", "edge"}


def test_a_tier_preferred_twice_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidSpec, match="preferredTiers"):
        _site(tmp_path, price=0, fleet_wish="[edge, edge]")


def test_the_lexicographic_choice_takes_the_cheapest_plan_among_those_that_miss_alike(
    tmp_path: Path,
) -> None:
    """The cloud is paid overflow: without cost among the objectives, the choice still
    prefers the cheapest of the front's plans that tie on the miss objectives."""
    from fogfleet.scheduling.choice import non_dominated

    p = _site(tmp_path, price=0.2)
    s = plan(p, SchedulerSettings(seed=2, generations=30, population=40))
    assert s.feasible and s.pareto_placements is not None and s.pareto_front is not None
    assert "cost" in s.choice_reason
    values = evaluate(p, s.pareto_placements, p.limits)
    tied = non_dominated(s.pareto_front)
    for name in ("missRate", "missedCycles"):  # the choice's tolerance (choice._lexicographic)
        col = values[name][tied]
        tied = tied[col <= col.min() + 1e-6 + 1e-3 * abs(col.min())]
    chosen = evaluate(p, s.placement[None, :], p.limits)["cost"][0]
    assert chosen <= values["cost"][tied].min() + 1e-9


def test_the_polish_quick_room_test_refuses_only_moves_the_constraints_refuse(
    tmp_path: Path,
) -> None:
    """``_has_room`` skips a move without the whole-plan check; it may only skip moves that
    check would refuse (else the polish would miss moves), and it must skip the overfull."""
    from fogfleet.scheduling.heuristics import Fit
    from fogfleet.scheduling.preference import _has_room
    from fogfleet.scheduling.stickiness import loads

    p = _site(tmp_path, price=1.0)
    x = plan(p, SchedulerSettings(seed=1)).placement
    fit, (used, _) = Fit(p, p.limits), loads(p, x)
    remote = np.flatnonzero(p.tier > 0)
    refused = kept = 0
    for i in np.flatnonzero(np.isin(x, remote)):
        nodes = remote[p.allowed[i, remote] & (remote != x[i])]
        for k, fits in zip(nodes, _has_room(fit, used, int(i), nodes), strict=True):
            trial = x.copy()
            trial[i] = k
            whole = bool(np.all(constraints(p, trial[None, :], p.limits) <= 1e-9))
            assert fits or not whole, f"instance {i} -> node {k}: refused but feasible"
            refused += not fits
            kept += fits
    # a plan over a full cluster: a quick test that refuses nothing would not be tested here
    used_full = used.copy()
    used_full[remote] = fit.cap[remote]
    anyone = int(np.flatnonzero(np.isin(x, remote))[0])
    assert not _has_room(fit, used_full, anyone, remote).any()
    assert kept > 0
