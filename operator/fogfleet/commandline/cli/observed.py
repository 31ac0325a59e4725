"""``fogfleet simulate --from-prometheus URL``: the fleet as it really runs (issue 10).

The modules' measured execution times (``fogfleet_execution_time_seconds`` in the fleet's
namespace) give each (module, hardware type) a correction of its declared profile, the same
blend the operator adopts on drift (``domain.observed.correction``). The cycle's noise needs
the plan the modules ran under, which the operator has and this command does not: here the
correction is the factor alone (the noise an operator adopted is in the module's status).
Every plan is then simulated with the corrected execution times: a plan made from the
declared profile shows what it really misses, and a re-plan made from the corrected one what
re-planning would gain, before anything is applied.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.controllers.measure.observed import declared_rows, read_observations
from fogfleet.controllers.measure.observed import describe as say
from fogfleet.domain.observed import correction
from fogfleet.domain.problem import Allocation, Problem
from fogfleet.domain.rows import Learnt, carry_noise

__all__ = ["learnt_corrections", "under_corrections"]


def learnt_corrections(
    url: str, fleet: RobotFleet, catalog: Catalog, window: int
) -> dict[tuple[str, str], tuple[Learnt, float]]:
    """(module, hardware type) -> (correction, measured cycles) from the fleet's namespace."""
    ns = fleet.metadata.namespace or "default"
    client = PrometheusClient(url)
    try:
        seen = read_observations(client, ns, window)
    finally:
        client.close()
    hardware = {n.spec.hardware_type: n for n in catalog.nodes.values()}
    out: dict[tuple[str, str], tuple[Learnt, float]] = {}
    for name, rows in sorted(seen.items()):
        module = catalog.module(ns, name)
        if module is None:
            continue
        raw = module.model_dump(by_alias=True, mode="json", exclude_none=True)
        drift = fleet.spec.drift
        learnt = correction(
            rows, declared_rows(raw, hardware), drift.prior_cycles, min_cycles=drift.min_cycles
        )
        for hw, got in learnt.items():
            out[(name, hw)] = got
    return out


def under_corrections(
    problem: Problem, allocation: Allocation, corrections: dict[tuple[str, str], Learnt]
) -> Allocation:
    """``allocation`` (a plan's CPU amounts and its rows) with the execution times each
    instance really has on each node: its rows as the correction of its module there makes
    them (``Learnt.row``; on a type where its noise is not known, the noise it shows
    elsewhere, as the planner takes it: ``rows.carry_noise``)."""
    scale = np.ones((problem.n_instances, problem.n_nodes))
    noise = np.zeros((problem.n_instances, problem.n_nodes))
    carried = carry_noise(corrections, (node.hardware_type for node in problem.nodes))
    for i, inst in enumerate(problem.instances):
        for j, node in enumerate(problem.nodes):
            got = carried.get((inst.module, node.hardware_type), Learnt())
            scale[i, j], noise[i, j] = got.factor, got.noise
    return Allocation(
        allocation.cpu_request,
        allocation.cpu_use,
        allocation.exe_mean * scale,
        np.hypot(allocation.exe_std * scale, noise),
        allocation.has_limit,
    )


def describe(learnt: dict[tuple[str, str], tuple[Learnt, float]]) -> Any:
    """One line per correction, for the table's header."""
    return [f"{m} on {say(hw, got, n)}" for (m, hw), (got, n) in sorted(learnt.items())]
