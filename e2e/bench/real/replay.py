"""A recorded run simulated again, under any execution model (offline, no cluster).

A run of ``bench-real.json`` records the placement the cluster ran (``Pending`` for a pod
kube-scheduler could not bind) and, since 2026-12-01, the CPU the plan gave each instance
(``cpu``, from the fleet's status). The allocation it ran with follows from its arm: the
kube-scheduler arms and on-board run the modules' nominal allocation (plain Deployments, no
limits; k8s-requests with its honest requests), the planner's arms the plan's rows at the
recorded CPU, at the first rung of the declared ladder where a run recorded none.
``replay`` rebuilds both and simulates the run's window with the run's seed and every module
active, as ``run.one_run`` did, so that ``DECLARED`` gives back the figures the run recorded
(``test_fit`` checks it on the committed document) and a fitted ``sim.ExecutionModel`` gives
what it predicts for the same run.

A closed-loop run may have run a re-plan's CPU that is no rung of the declared ladder (its
rows were the learnt ones), or recorded none (before 2026-12-01): its replay then runs the
nearest it can, and ``cpu_known`` says whether a run's replay is exact.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from e2e.bench.real.measure import counting_unrun, simulated_rates
from e2e.bench.real.protocol import ONBOARD, PENDING, REQUESTS
from e2e.bench.real.scenario import Scenario
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.commandline.cli.planning import rung_of
from fogfleet.domain.problem import Allocation
from fogfleet.sim import ExecutionModel

__all__ = ["cpu_known", "replay", "scenario_of"]

Run = Mapping[str, Any]
NOMINAL = frozenset({"k8s-default", REQUESTS, ONBOARD})  # plain Deployments: no limits


@functools.cache
def _scenarios() -> tuple[Scenario, Scenario]:
    base = Scenario()
    return base, base.with_honest_requests()


def scenario_of(arm: str) -> Scenario:
    """The fleet a run of ``arm`` applied (k8s-requests: with its honest requests)."""
    base, honest = _scenarios()
    return honest if arm == REQUESTS else base


def _placement(run: Run, scenario: Scenario) -> tuple[Any, list[tuple[str, str]]]:
    problem = scenario.problem
    placement = np.full(problem.n_instances, -1, dtype=np.int64)
    pending: list[tuple[str, str]] = []
    recorded: Mapping[str, str] = run["placement"]
    for i, inst in enumerate(problem.instances):
        key = f"{inst.robot}/{inst.module}"
        if key not in recorded:
            raise ValueError(f"run {run.get('position')}: placement has no {key}")
        if recorded[key] == PENDING:
            pending.append((inst.module, inst.robot))
        else:
            placement[i] = problem.node_index(recorded[key])
    return placement, pending


def cpu_known(run: Run) -> bool:
    """Whether ``replay`` runs ``run`` with the CPU it ran with (module docstring): plain
    Deployments always; a planner's run when it never re-planned from learnt rows, or when
    every CPU it recorded is a rung of the declared ladder."""
    arm = str(run["scheduler"])
    if arm in NOMINAL or not run.get("corrected"):
        return True
    recorded: Mapping[str, str] | None = run.get("cpu")
    if not recorded:
        return False
    scenario = scenario_of(arm)
    placement, _ = _placement(run, scenario)
    allocation = _allocation(run, scenario, placement)
    for i, inst in enumerate(scenario.problem.instances):
        cpu = recorded.get(f"{inst.robot}/{inst.module}")
        j = int(placement[i])
        if cpu is not None and j >= 0 and abs(allocation.cpu_use[i, j] - parse_cpu(cpu)) > 1e-6:
            return False
    return True


def _allocation(run: Run, scenario: Scenario, placement: Any) -> Allocation:
    problem = scenario.problem
    if str(run["scheduler"]) in NOMINAL:
        return problem.nominal
    levels = np.zeros(problem.n_instances, dtype=np.int64)
    recorded: Mapping[str, str] = run.get("cpu") or {}
    for i, inst in enumerate(problem.instances):
        cpu = recorded.get(f"{inst.robot}/{inst.module}")
        if cpu is not None and placement[i] >= 0:
            levels[i] = rung_of(problem, i, int(placement[i]), cpu)
    return problem.with_levels(levels).limits


def replay(run: Run, model: ExecutionModel) -> dict[str, float]:
    """Per module, the miss rate ``model`` gives the completed ``run`` (an instance left
    Pending misses every cycle it was due, as in the run's own record)."""
    arm = str(run["scheduler"])
    scenario = scenario_of(arm)
    placement, pending = _placement(run, scenario)
    window = float(run["windowSeconds"])
    sim = model.simulate(
        scenario.problem,
        placement,
        _allocation(run, scenario, placement),
        window,
        int(run["seed"]),
        all_active=True,
    )
    rates = simulated_rates(sim.module_miss_rate, sim.module_cycles)
    return dict(counting_unrun(rates, scenario.due_cycles(pending, window)).modules)
