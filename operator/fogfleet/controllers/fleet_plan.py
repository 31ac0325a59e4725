"""Plan a fleet: run the planner when the planning inputs changed (fingerprint cache), apply
the migration-margin rule to what runs, and explain an infeasible fleet by node and resource.
"""

from __future__ import annotations

import hashlib
import logging
import time

import numpy as np

from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible
from fogfleet.render.deployments import format_cpu
from fogfleet.scheduling import stickiness

from .deps import CachedPlan, Deps, FleetKey
from .status import now

__all__ = ["plan_fleet"]

log = logging.getLogger(__name__)


def plan_fleet(
    deps: Deps, key: FleetKey, problem: Problem, fleet: RobotFleet, before: np.ndarray
) -> tuple[CachedPlan, bool]:
    given = fleet.spec.scheduler
    defaults = {k: v for k, v in deps.scheduler_defaults.items() if k not in given.model_fields_set}
    settings = given.model_copy(update=defaults) if defaults else given
    fp = stickiness.fingerprint(problem, settings)
    cached = deps.plans.get(key)
    if cached is not None and cached.fingerprint == fp:
        return cached, False
    failed = deps.failures.get(key)
    if failed is not None and failed[0] == fp:
        raise failed[1]  # same inputs, same failure: do not run the GA again
    t0 = time.perf_counter()
    schedule = deps.planner.plan(problem, settings)
    seconds = time.perf_counter() - t0
    placement = np.asarray(schedule.placement, dtype=np.int64)
    if not schedule.feasible or not stickiness.feasible(problem, placement, True):
        err = Infeasible(
            f"RobotFleet/{key[1]}",
            "spec",
            _infeasible_message(problem, placement, schedule.reasons),
        )
        deps.failures[key] = (fp, err)
        raise err
    deps.failures.pop(key, None)
    stick = stickiness.keep_running(problem, placement, settings)
    plan_id = hashlib.sha256(f"{fp}:{stick.placement.tobytes().hex()}".encode()).hexdigest()[:12]
    reason = schedule.choice_reason
    if stick.kept_current or stick.migrations:
        reason = f"{reason}; {stick.reason}" if reason else stick.reason
    chosen = stick.placement
    moves = tuple(
        f"{problem.label(i)} {problem.nodes[before[i]].name}->{problem.nodes[chosen[i]].name}"
        for i in range(problem.n_instances)
        if before[i] >= 0 and chosen[i] >= 0 and chosen[i] != before[i]
    )
    # the migration-margin rule may keep what runs: report the deployed plan, not the proposal
    objectives = (
        dict(schedule.objectives)
        if np.array_equal(chosen, placement)
        else stickiness.objective_values(problem, chosen, True, list(schedule.objectives))
    )
    cached = CachedPlan(fp, schedule, chosen, plan_id, len(moves), reason, now(), moves, objectives)
    deps.plans[key] = cached
    deps.metrics.observe_plan(key[1], schedule.scheduler, seconds, objectives)
    deps.metrics.count_migrations(key[1], len(moves))
    log.info(
        "Planned RobotFleet %s/%s in %.0f ms (%d migrations)",
        *key,
        seconds * 1e3,
        len(moves),
    )
    return cached, True


def _infeasible_message(problem: Problem, placement: np.ndarray, reasons: dict[int, str]) -> str:
    """Say what cannot fit where: single modules larger than every node they may use, then
    the constraints the best plan found still violates."""
    from fogfleet.scheduling.objectives import constraint_names, constraints

    parts: list[str] = []
    need = {"cpu": problem.limits.cpu_request, "memory": problem.memory, "gpu": problem.gpu}
    for i in range(problem.n_instances):
        nodes = np.flatnonzero(problem.allowed[i])
        for r, (name, demand) in enumerate(need.items()):
            d = demand[i, nodes] if demand.ndim == 2 else np.full(len(nodes), demand[i])
            if len(nodes) and np.all(d > problem.capacity[nodes, r] + 1e-9):
                biggest = int(nodes[np.argmax(problem.capacity[nodes, r])])
                parts.append(
                    f"{problem.label(i)} needs {_amount(name, float(d.min()))} {name} but "
                    f"the largest node it may use ({problem.nodes[biggest].name}) has "
                    f"{_amount(name, float(problem.capacity[biggest, r]))}"
                )
    if not parts:
        g = constraints(problem, placement[None, :], problem.limits)[0]
        names = constraint_names(problem)
        parts = [f"{n} over by {v * 100:.0f}%" for n, v in zip(names, g, strict=True) if v > 1e-9][
            :8
        ]
    head = "no placement fits the fleet's nodes"
    detail = "; ".join(parts[:8]) or "; ".join(reasons.values()) or "constraints violated"
    return f"{head}: {detail}"


def _amount(resource: str, value: float) -> str:
    if resource == "memory":
        return f"{value / 2**30:.1f}Gi"
    if resource == "cpu":
        return format_cpu(value)
    return f"{value:g}"
