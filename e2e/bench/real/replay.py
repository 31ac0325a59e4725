"""A recorded run simulated again, under any execution model (offline, no cluster).

A run of ``bench-real.json`` records the placement the cluster ran (``Pending`` for a pod
kube-scheduler could not bind). The allocation it ran with follows from its arm: the
kube-scheduler arms and on-board run the modules' nominal allocation (plain Deployments, no
limits; k8s-requests with its honest requests), the planner's arms the plan's rows at their
limits. ``replay`` rebuilds both and simulates the run's window with the run's seed and every
module active, as ``run.one_run`` did, so that ``DECLARED`` gives back the figures the run
recorded (``e2e/bench/real/test_replay.py`` checks it on the committed document) and a fitted
``sim.ExecutionModel`` gives what it predicts for the same run.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from e2e.bench.real.measure import counting_unrun, simulated_rates
from e2e.bench.real.protocol import ONBOARD, PENDING, REQUESTS
from e2e.bench.real.scenario import Scenario
from fogfleet.domain.problem import Allocation
from fogfleet.sim import ExecutionModel

__all__ = ["replay", "scenario_of"]

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


def _allocation(arm: str, scenario: Scenario) -> Allocation:
    problem = scenario.problem
    if arm in NOMINAL:
        return problem.nominal
    return problem.with_levels(np.zeros(problem.n_instances, dtype=np.int64)).limits


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
        _allocation(arm, scenario),
        window,
        int(run["seed"]),
        all_active=True,
    )
    rates = simulated_rates(sim.module_miss_rate, sim.module_cycles)
    return dict(counting_unrun(rates, scenario.due_cycles(pending, window)).modules)
