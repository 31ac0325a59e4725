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

from fogfleet.adapters.prometheus import PrometheusClient
from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.controllers.measure.observed import declared_rows, read_observations
from fogfleet.controllers.measure.observed import describe as say
from fogfleet.domain.observed import correction
from fogfleet.domain.rows import Learnt

__all__ = ["learnt_corrections"]


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


def describe(learnt: dict[tuple[str, str], tuple[Learnt, float]]) -> Any:
    """One line per correction, for the table's header."""
    return [f"{m} on {say(hw, got, n)}" for (m, hw), (got, n) in sorted(learnt.items())]
