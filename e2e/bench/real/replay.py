"""A recorded run simulated again, under any execution model (offline, no cluster).

A run of ``bench-real.json`` records the placement the cluster ran (``Pending`` for a pod
kube-scheduler could not bind) and, since 2026-12-01, the CPU the plan gave each instance
(``cpu``, from the fleet's status). The allocation it ran with follows from its arm: the
kube-scheduler arms and on-board run the modules' nominal allocation (plain Deployments, no
limits; k8s-requests with its honest requests), the planner's arms the plan's rows at the
recorded CPU, at the first rung of the declared ladder where a run recorded none.
``replay`` reads both back as the run itself did (``Scenario.placement_of`` on the status
the run recorded) and simulates the run's window with the run's seed and every module
active, as ``run.one_run`` did, so that ``DECLARED`` gives back the figures the run recorded
(``test_fit`` checks it on the committed document) and a fitted ``sim.ExecutionModel`` gives
what it predicts for the same run.

A closed-loop run may have run a re-plan's CPU that is no rung of the declared ladder (its
rows were the learnt ones), or recorded none (before 2026-12-01): its replay then runs the
first rung, and ``cpu_known`` says whether a run's replay is exact.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

from e2e.bench.real.measure import counting_unrun, simulated_rates
from e2e.bench.real.protocol import ONBOARD, PENDING, REQUESTS
from e2e.bench.real.scenario import Scenario
from fogfleet.api.v1alpha1.base import parse_cpu
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


def _ran(run: Run, scenario: Scenario) -> tuple[Any, Allocation, list[tuple[str, str]]]:
    """The placement and allocation ``run`` ran with, read back as the run itself read them
    (``Scenario.placement_of`` on the status it recorded), and its Pending instances."""
    arm = str(run["scheduler"])
    recorded: Mapping[str, str] = run["placement"]
    cpu: Mapping[str, str] = run.get("cpu") or {}
    entries, pending = [], []
    for inst in scenario.problem.instances:
        key = f"{inst.robot}/{inst.module}"
        if key not in recorded:
            raise ValueError(f"run {run.get('position')}: placement has no {key}")
        if recorded[key] == PENDING:
            pending.append((inst.module, inst.robot))
        else:
            entries.append({"robot": inst.robot, "module": inst.module,
                            "node": recorded[key], "cpu": cpu.get(key)})  # fmt: skip
    status = {"scheduler": arm, "withLimits": arm not in NOMINAL, "placement": entries}
    placement, allocation = scenario.placement_of({"status": status})
    return placement, allocation, pending


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
    placement, allocation, _ = _ran(run, scenario)
    for i, inst in enumerate(scenario.problem.instances):
        cpu = recorded.get(f"{inst.robot}/{inst.module}")
        j = int(placement[i])
        if cpu is not None and j >= 0 and abs(allocation.cpu_use[i, j] - parse_cpu(cpu)) > 1e-6:
            return False
    return True


def replay(run: Run, model: ExecutionModel) -> dict[str, float]:
    """Per module, the miss rate ``model`` gives the completed ``run`` (an instance left
    Pending misses every cycle it was due, as in the run's own record)."""
    arm = str(run["scheduler"])
    scenario = scenario_of(arm)
    placement, allocation, pending = _ran(run, scenario)
    window = float(run["windowSeconds"])
    sim = model.simulate(
        scenario.problem,
        placement,
        allocation,
        window,
        int(run["seed"]),
        all_active=True,
    )
    rates = simulated_rates(sim.module_miss_rate, sim.module_cycles)
    return dict(counting_unrun(rates, scenario.due_cycles(pending, window)).modules)
