"""Each objective on the tiny fleet, computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.objectives import (
    balance,
    constraint_names,
    constraints,
    cost,
    energy,
    evaluate,
    migrations,
    missedCycles,
    missRate,
    onboard,
    reserve,
)

# plan A: everything on board; plan B: m1 on n1, m2 on n2; plan C: m1 and m2 on n1
X = np.array([[0, 0, 0], [0, 1, 2], [0, 1, 1]])


def test_onboard_sums_cpu_and_memory_shares_of_robots(tiny: Problem) -> None:
    f1 = onboard(tiny, X, tiny.limits)
    # A: cpu (1*1 + 0.5*1 + 0.2*1)/2 = 0.85, memory (1+2+1)/4 = 1
    # B: cpu 1/2, memory 1/4
    assert f1 == pytest.approx([1.85, 0.75, 0.75])


def test_reserve_is_peak_requested_utilisation(tiny: Problem) -> None:
    # A: robot requests 3 of 2 cores -> 1.5; B: n1 2/4 cpu, robot 1/2, memory 2/8 -> 0.5
    # C: n1 requests 3 of 4 cores -> 0.75
    assert reserve(tiny, X, tiny.limits) == pytest.approx([1.5, 0.5, 0.75])


def test_balance_is_std_over_edge_nodes(tiny: Problem) -> None:
    # B: expected cpu 0.5*2/4=0.25 and 0.2*1/4=0.05 -> std 0.1; memory 2/8, 1/8 -> std 0.0625
    # C: n1 cpu (1 + 0.2)/4 = 0.3, n2 0 -> std 0.15; memory 3/8, 0 -> 0.1875
    assert balance(tiny, X, tiny.limits) == pytest.approx([0.0, 0.1625, 0.3375])


def test_missed_cycles_use_the_contention_factor(tiny: Problem) -> None:
    # A: robot load 1 + 0.5 + 0.2 = 1.7 of 2 cores -> kappa 1;
    #    tau m0 0.5, m1 0.5, m2 0.5 -> nothing missed
    # B: m1 tau = (0.15 + 0.1)/0.2 = 1.25 -> 0.5 * 1.25; m2 (0.1 + 0.4)/1 = 0.5
    assert missedCycles(tiny, X, tiny.limits) == pytest.approx([0.0, 0.625, 0.625])


def test_missed_cycles_grow_with_overload(tiny: Problem) -> None:
    heavy = np.array([[0, 0, 0]])
    alloc = tiny.limits
    # double the use of m2 on the robot: load 1 + 0.5 + 0.2*... use a 3-core m2 instead
    use = alloc.cpu_use.copy()
    use[2, 0] = 4.0
    from dataclasses import replace

    al2 = replace(alloc, cpu_use=use)
    # load = 1 + 0.5 + 0.2 * 4 = 2.3 -> kappa 1.15; m2 tau = 0.5 * 1.15 / 1 < 1, m1 0.575, m0 0.575
    assert missedCycles(tiny, heavy, al2) == pytest.approx([0.0])
    use[1, 0] = 8.0  # load 1 + 4 + 0.8 = 5.8 -> kappa 2.9: m0 tau 1.45, m1 1.45, m2 1.45
    al3 = replace(alloc, cpu_use=use)
    assert missedCycles(tiny, heavy, al3) == pytest.approx([1.45 + 0.5 * 1.45 + 0.2 * 1.45])


def test_miss_rate_is_the_mean_over_modules(tiny: Problem) -> None:
    # three modules of one instance each; std 0 -> steps: B: only m1 misses (0.25 > 0.2), so
    # the modules' rates are 0, 1, 0 (activation weighs instances within a module only)
    assert missRate(tiny, X, tiny.limits) == pytest.approx([0.0, 1 / 3, 1 / 3])


def test_miss_rate_of_normal_cycle_is_its_tail(tiny: Problem) -> None:
    from dataclasses import replace

    sd = np.zeros((3, 3))
    sd[2, 0] = 0.5  # m2 on board: mean 0.5, std 0.5, T = 1 -> P = 1 - Phi(1) = 0.158655
    al = replace(tiny.limits, exe_std=sd)
    assert missRate(tiny, np.array([[0, 1, 0]]), al)[0] == pytest.approx(
        (1 + 0.158655) / 3, rel=1e-4
    )


def test_cost_and_energy(tiny: Problem) -> None:
    # B: 2 cores on n1 * 0.05 + 1 core on n2 * 0.04 = 0.14
    assert cost(tiny, X, tiny.limits) == pytest.approx([0.0, 0.14, 0.10 + 0.05])
    # A: 10 + 5 * 1.7 = 18.5 W; B: 10 + 5 * 1 + 0.1 * 50 Mbps = 20
    assert energy(tiny, X, tiny.limits) == pytest.approx([18.5, 20.0, 20.0])


def test_migrations_count_running_instances_the_plan_moves(tiny: Problem) -> None:
    import dataclasses

    # m0 runs on n0 and m2 on n2 now, m1 nowhere yet (a new instance never counts)
    running = dataclasses.replace(tiny, current=np.array([0, -1, 2]))
    assert migrations(running, X, running.limits) == pytest.approx([1.0, 0.0, 1.0])
    assert migrations(running, np.array([[0, -1, -1]]), running.limits) == pytest.approx([0.0])
    assert migrations(tiny, X, tiny.limits) == pytest.approx([0.0, 0.0, 0.0])  # nothing runs


def test_unplaced_instances_contribute_nothing(tiny: Problem) -> None:
    x = np.array([[0, -1, -1]])
    vals = evaluate(tiny, x, tiny.limits)
    assert vals["onboard"] == pytest.approx([0.5 + 0.25])
    assert vals["missRate"] == pytest.approx([0.0])


def test_constraints_flag_capacity_uplink_and_gene_space(tiny: Problem) -> None:
    names = constraint_names(tiny)
    G = constraints(tiny, np.array([[0, 0, 0], [0, 1, 2], [1, 1, 1], [0, 0, 2]]), tiny.limits)
    assert G.shape == (4, len(names))
    col = {n: k for k, n in enumerate(names)}
    assert G[0, col["cpu:n0"]] == pytest.approx(0.5)  # 3 of 2 cores
    # B sends 40 + 10 Mbps over a 50 Mbps uplink, whose 80% is 40
    assert G[1, col["uplink:n0"]] == pytest.approx((50e6 - 40e6) / 40e6)
    assert G[2, col["geneSpace"]] == 1.0  # m0 off its robot
    assert np.all(G[3] <= 0)  # 2 of 2 cores on board, 10 Mbps off board


def test_every_objective_the_api_accepts_is_evaluated_both_ways() -> None:
    from fogfleet.api.v1alpha1.robotfleet import ObjectiveName
    from fogfleet.scheduling.objectives import EVALUATORS, OBJECTIVES

    names = {o.value for o in ObjectiveName}
    assert set(EVALUATORS) == names
    assert set(OBJECTIVES) == names


def test_module_miss_rates_make_up_the_fleets_miss_rate() -> None:
    """One definition: the fleet's missRate is the mean of the per-module predictions (the
    plan's per-module table cannot disagree with its total)."""
    from fogfleet.api.loader import load_paths
    from fogfleet.bench.scheduling import WAREHOUSE
    from fogfleet.domain.build import build_problem
    from fogfleet.scheduling.baselines import onboard_plan
    from fogfleet.scheduling.objectives import module_miss_rates

    catalog = load_paths([WAREHOUSE])
    problem = build_problem(catalog.fleets[0], catalog)
    schedule = onboard_plan(problem)  # everything on board: some modules miss
    rates = module_miss_rates(problem, schedule.placement, schedule.with_limits)
    assert set(rates) == {inst.module for inst in problem.instances}
    assert max(rates.values()) > 0.01
    total = sum(rates.values()) / len(rates)
    assert total == pytest.approx(schedule.objectives["missRate"], rel=1e-9, abs=1e-12)


def test_balance_is_taken_within_each_tier_so_an_idle_cloud_is_not_a_debt(
    edge_and_cloud: Problem,
) -> None:
    """Two edge and two cloud nodes, two equal instances: one on each edge node is perfectly
    balanced (the idle cloud is no debt); one edge + one cloud node leaves both tiers uneven;
    lumping the tiers together would have rated those two plans alike."""
    plans = np.array([[1, 2], [1, 3]])
    edge_even, across = balance(edge_and_cloud, plans, edge_and_cloud.limits)
    assert edge_even == pytest.approx(0.0)
    assert across > 0.2  # each tier: one node at 0.25 of its CPU, the other idle
