"""Graceful degradation (scheduling.degrade): a site short of CPU gets a plan whose misses fall
on its lowest-priority modules, never on hard real-time ones; other shortages stay refused."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.degrade import give_back, steps
from fogfleet.scheduling.objectives import evaluate
from fogfleet.scheduling.solver import plan

ROOT = Path(__file__).resolve().parents[3]
SOLO = ROOT / "manifests" / "examples" / "single-robot"


def _site(tmp_path: Path, edge_cpu: str, *, memory: str = "64Gi", modules: str = "") -> Problem:
    """The single-robot fleet with an edge node of ``edge_cpu`` cores (16 in the example)."""
    nodes = (SOLO / "nodes.yaml").read_text()
    old = "capacity: {cpu: 16, memory: 64Gi}"
    assert old in nodes
    (tmp_path / "nodes.yaml").write_text(
        nodes.replace(old, f"capacity: {{cpu: {edge_cpu}, memory: {memory}}}")
    )
    (tmp_path / "fleet.yaml").write_text((SOLO / "fleet.yaml").read_text())
    (tmp_path / "modules.yaml").write_text(modules or (SOLO / "modules.yaml").read_text())
    catalog = load_paths([tmp_path])
    return build_problem(catalog.fleets[0], catalog)


def _settings(problem: Problem, **extra: object):  # type: ignore[no-untyped-def]
    from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings

    return SchedulerSettings.model_validate({"generations": 20, "population": 24, **extra})


def _degraded_modules(problem: Problem, levels: np.ndarray) -> set[str]:
    return {problem.instances[i].module for i in np.flatnonzero(levels > 0)}


def test_the_taxonomy_gives_default_priorities_and_hard_real_time_has_no_rungs(
    tmp_path: Path,
) -> None:
    p = _site(tmp_path, "2")
    prio = {inst.module: int(p.priority[i]) for i, inst in enumerate(p.instances)}
    assert prio["nav-controller"] == 1000  # hard real-time, safety-critical
    assert prio["nav-localization"] == 700  # safety-relevant
    assert prio["scene-segmentation"] == 400  # soft real-time, safety-irrelevant
    assert prio["object-pose-estimation"] == 100
    assert p.ladder is not None
    ctrl = [i for i, inst in enumerate(p.instances) if inst.module == "nav-controller"]
    assert not p.ladder.depth[ctrl].any(), "a hard real-time module is never degraded"
    order = steps(p)
    assert [int(p.priority[i]) for i in order] == sorted(int(p.priority[i]) for i in order)


def test_a_site_short_of_cpu_runs_degraded_on_its_lowest_priorities(tmp_path: Path) -> None:
    # 14.75 cores wanted, 6 + 8 allocatable: one core short, which object pose (priority 100,
    # 2 cores for its deadline, 1 core profiled) can give
    p = _site(tmp_path, "8500m")
    sched = plan(p, _settings(p))
    assert sched.feasible and sched.degraded
    assert sched.levels is not None
    degraded = p.with_levels(sched.levels)
    # the degraded problem's CPU amounts fit the nodes and its figures are the schedule's
    values = evaluate(degraded, sched.placement[None, :], degraded.limits)
    assert sched.objectives["missRate"] == pytest.approx(float(values["missRate"][0]))
    lowest = {
        inst.module
        for i, inst in enumerate(p.instances)
        if p.priority[i] == p.priority[steps(p)].min()
    }
    assert _degraded_modules(p, sched.levels) == lowest == {"object-pose-estimation"}
    assert "priority 100" in sched.choice_reason and "predicted miss" in sched.choice_reason


def test_refusing_degradation_keeps_the_fleet_infeasible(tmp_path: Path) -> None:
    p = _site(tmp_path, "3")
    sched = plan(p, _settings(p, allowDegraded=False))
    assert not sched.feasible and not sched.degraded


def test_a_memory_shortage_is_not_degraded_away(tmp_path: Path) -> None:
    modules = (SOLO / "modules.yaml").read_text()
    old = 'resources: {cpu: "500m", memory: 1Gi}'
    assert old in modules
    # a 20 GiB module fits neither the robot (14 GiB) nor a 2 GiB edge: less CPU cannot help
    p = _site(
        tmp_path, "3", memory="2Gi", modules=modules.replace(old, old.replace("1Gi", "20Gi"), 1)
    )
    sched = plan(p, _settings(p))
    assert not sched.feasible and not sched.degraded


def test_a_users_priority_decides_who_degrades_first(tmp_path: Path) -> None:
    modules = (SOLO / "modules.yaml").read_text()
    # object pose matters most now; scene segmentation least
    modules = modules.replace(
        "  name: object-pose-estimation\n", "  name: object-pose-estimation\n", 1
    )
    docs = modules.split("\n---\n")
    for k, doc in enumerate(docs):
        if "name: object-pose-estimation\n" in doc:
            docs[k] = doc.replace("\nspec:\n", "\nspec:\n  priority: 900\n", 1)
        if "name: scene-segmentation\n" in doc:
            docs[k] = doc.replace("\nspec:\n", "\nspec:\n  priority: 5\n", 1)
    p = _site(tmp_path, "8500m", modules="\n---\n".join(docs))
    sched = plan(p, _settings(p))
    assert sched.feasible and sched.degraded and sched.levels is not None
    got = _degraded_modules(p, sched.levels)
    assert "scene-segmentation" in got and "object-pose-estimation" not in got


def test_rungs_the_plan_has_room_for_are_given_back(tmp_path: Path) -> None:
    p = _site(tmp_path, "16")  # the example: nothing short
    sched = plan(p, _settings(p))
    assert sched.feasible and not sched.degraded
    every = np.ones(p.n_instances, dtype=np.int64)
    back = give_back(p.with_levels(every), sched.placement)
    assert not back.any(), "the plan fits at full CPU, so every rung comes back"


def test_a_fleet_may_override_a_modules_priority(tmp_path: Path) -> None:
    p = _site(tmp_path, "8500m")
    fleet = (tmp_path / "fleet.yaml").read_text()
    old = "  - name: object-pose-estimation\n"
    assert old in fleet
    (tmp_path / "fleet.yaml").write_text(
        fleet.replace(old, old + "    overrides: {priority: 900}\n")
    )
    catalog = load_paths([tmp_path])
    q = build_problem(catalog.fleets[0], catalog)
    for i, inst in enumerate(q.instances):
        expected = 900 if inst.module == "object-pose-estimation" else int(p.priority[i])
        assert int(q.priority[i]) == expected
    sched = plan(q, _settings(q))
    assert sched.degraded and sched.levels is not None
    assert "object-pose-estimation" not in _degraded_modules(q, sched.levels)


def test_a_plan_that_fits_never_builds_the_ladder_and_derived_problems_share_it(
    tmp_path: Path,
) -> None:
    # the (I, N, K) arrays are most of a large fleet's problem: only a degrading plan reads them
    p = _site(tmp_path, "16")
    sched = plan(p, _settings(p))
    assert sched.feasible and not sched.degraded
    assert p.ladder_source is not None and not p.ladder_source.built
    masked = replace(p, allowed=np.zeros_like(p.allowed))
    ladder = masked.ladder
    assert ladder is not None and p.ladder_source.built
    assert p.ladder is ladder, "problems derived from one build share its ladder"
    pose = next(i for i, inst in enumerate(p.instances) if inst.module == "object-pose-estimation")
    j = int(p.home[pose])
    # rung 0 is the limits pick, rung 1 the 1-core row of the profile
    assert ladder.cpu[pose, j, 0] == p.limits.cpu_request[pose, j] == 2.0
    assert ladder.cpu[pose, j, 1] == 1.0 and ladder.mean[pose, j, 1] == pytest.approx(0.38)


def test_the_plan_fingerprint_follows_a_smaller_profiled_cpu(tmp_path: Path) -> None:
    from fogfleet.scheduling.stickiness import fingerprint

    modules = (SOLO / "modules.yaml").read_text()
    row = "{hardwareType: default, cpu: 1, meanMillis: 380, stdMillis: 70}"
    assert row in modules
    for d in "abc":
        (tmp_path / d).mkdir()
    a = _site(tmp_path / "a", "16", modules=modules)
    b = _site(tmp_path / "b", "16", modules=modules.replace(row, row.replace("380", "390")))
    # the pick (2 cores) and the nominal row (4 cores) are the same: only the ladder differs
    assert np.array_equal(a.limits.exe_mean, b.limits.exe_mean)
    assert np.array_equal(a.nominal.exe_mean, b.nominal.exe_mean)
    settings = _settings(a)
    assert fingerprint(a, settings) != fingerprint(b, settings)
    assert fingerprint(a, settings) == fingerprint(
        _site(tmp_path / "c", "16", modules=modules), settings
    )
    assert a.ladder_source is not None and not a.ladder_source.built


def test_a_budget_spent_ends_the_search_for_the_fewest_rungs_and_gives_rungs_back(
    tmp_path: Path,
) -> None:
    from fogfleet.scheduling.degrade import degrade, levels_of
    from fogfleet.scheduling.solver import nsga2

    p = _site(tmp_path, "8500m")
    order = steps(p)
    full = degrade(p, lambda q: nsga2(q, _settings(q)))
    cut = degrade(p, lambda q: nsga2(q, _settings(q)), stop=lambda: True)
    assert full is not None and cut is not None and cut.feasible and cut.levels is not None
    assert "ended the search for the fewest rungs" in cut.choice_reason
    assert "ended the search" not in full.choice_reason
    # it planned with every rung taken, then gave back what the plan has room for
    assert 0 < int(cut.levels.sum()) < int(levels_of(p, order, len(order)).sum())
    degraded = p.with_levels(cut.levels)
    assert np.all(degraded.limits.cpu_request[np.arange(p.n_instances), cut.placement] > 0)


def test_a_degraded_plan_keeps_the_budget_of_the_whole_plan(tmp_path: Path) -> None:
    from .conftest import StepClock

    p = _site(tmp_path, "8500m")
    # every reading of the clock takes a second: the first search alone spends the 1 s budget
    sched = plan(p, _settings(p, timeBudgetMillis=1000), clock=StepClock(1.0))
    assert sched.feasible and sched.degraded
    # the degradation's search and the degraded NSGA-II count from the plan's start
    assert "ended the search for the fewest rungs" in sched.choice_reason
    assert "time budget of 1 s reached" in sched.choice_reason and sched.budget_cut
    took = re.search(r"planning took ([0-9.]+) s", sched.choice_reason)
    assert took is not None and float(took.group(1)) >= sched.duration_seconds - 2


@pytest.fixture
def searched(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Per NSGA-II search ``plan`` runs, whether its problem was degraded."""
    from fogfleet.scheduling import solver

    seen: list[bool] = []
    real = solver.nsga2

    def spy(problem: Problem, *args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        seen.append(problem.degraded)
        return real(problem, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(solver, "nsga2", spy)
    return seen


def test_a_site_short_of_cpu_in_all_is_degraded_without_a_search_at_full_cpu(
    tmp_path: Path, searched: list[bool]
) -> None:
    from fogfleet.scheduling.degrade import short_of_cpu

    for d in ("short", "room"):
        (tmp_path / d).mkdir()
    short = _site(tmp_path / "short", "8500m")  # 14.75 cores wanted, 6 + 8.5 in all
    assert short_of_cpu(short)
    assert not short_of_cpu(_site(tmp_path / "room", "16"))
    sched = plan(short, _settings(short))
    assert sched.feasible and sched.degraded
    assert searched == [True], "only the degraded problem is searched"


def test_a_site_not_proved_short_is_searched_at_full_cpu_first(
    tmp_path: Path, searched: list[bool]
) -> None:
    from fogfleet.scheduling.degrade import short_of_cpu

    for d in "ab":
        (tmp_path / d).mkdir()
    assert short_of_cpu(_site(tmp_path / "a", "3"))  # 9 cores in all for 14.75
    p = _site(tmp_path / "b", "8750m")  # 14.75 in all: only a search can tell
    assert not short_of_cpu(p)
    sched = plan(p, _settings(p))
    assert searched == [False] and sched.feasible and not sched.degraded


def test_a_search_for_the_fewest_rungs_cut_early_makes_its_first_try_and_ends_near_them() -> None:
    from fogfleet.bench.scheduling import synthetic_fleet
    from fogfleet.scheduling.degrade import _fewest_rungs, levels_of, packs, prefix_need

    cat, fleet = synthetic_fleet(20, 2, 1)  # 20 robots on 2 edges: short of CPU
    p = build_problem(fleet, cat)
    order = steps(p)
    need = prefix_need(p, order)
    cap = float(p.capacity[:, 0].sum())
    assert need[0] > cap and np.all(np.diff(need) <= 1e-12)
    # a prefix the bound proves short does not pack, whatever the packing tries
    proved = int(np.argmax(need <= cap)) - 1
    assert proved > 0 and packs(p.with_levels(levels_of(p, order, proved))) is None
    lo, hi = _fewest_rungs(p, order, lambda: False)
    assert hi == lo + 1 and lo >= proved
    tries = iter([False])  # one try, then the budget is spent
    _, early = _fewest_rungs(p, order, lambda: next(tries, True))
    assert hi <= early <= hi + 0.05 * len(order) < len(order)
    # a budget spent before the search began still gets its first try, not every rung
    _, spent = _fewest_rungs(p, order, lambda: True)
    assert hi <= spent <= hi + 0.05 * len(order) < len(order)
