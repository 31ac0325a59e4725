"""Why a fleet cannot be placed, in one sentence a person can act on: used by the operator's
``Ready=False`` condition and Event and by the CLI alike."""

from __future__ import annotations

import numpy as np

from fogfleet.api.v1alpha1.base import format_cores
from fogfleet.domain.miss_rates import format_miss_rate
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.objectives import constraint_names, constraints, module_miss_rates

__all__ = ["degraded_message", "infeasible_message", "unplaced_reasons"]


def unplaced_reasons(problem: Problem, reasons: dict[int, str]) -> dict[str, str]:
    """The solver's reasons by what they are about: an instance's label, or ``fleet`` for the
    fleet-level reason (index -1, which is no instance)."""
    return {("fleet" if i < 0 else problem.label(i)): why for i, why in sorted(reasons.items())}


def infeasible_message(problem: Problem, placement: np.ndarray, reasons: dict[int, str]) -> str:
    """Say what cannot fit where: modules that fit no node at all (with the rule that forbids
    each node: privacy, devices, hard real time, tier), single modules larger than every node
    they may use, then the constraints the best plan found still violates."""

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
    fits_nowhere = [why for i, why in sorted(reasons.items()) if i >= 0 and why]
    short = _gpu_shortfall(problem)
    if short:
        parts.insert(0, short)
    if not parts and not fits_nowhere:
        g = constraints(problem, placement[None, :], problem.limits)[0]
        names = constraint_names(problem)
        parts = [_violation(n, v) for n, v in zip(names, g, strict=True) if v > 1e-9][:8]
    head = "no placement fits the fleet's nodes"
    detail = "; ".join([*fits_nowhere[:4], *parts[:8]]) or "constraints violated"
    return f"{head}: {detail}{_reserve_note(problem)}"


def _violation(column: str, value: float) -> str:
    """One violated column of ``constraints`` (``constraint_names``) in words."""
    if column == "geneSpace":  # a count of instances, not a ratio
        return f"{value:.0f} instance(s) on a node their module may not use"
    what, _, node = column.partition(":")
    label = {"cpu": "CPU requests", "memory": "memory", "gpu": "GPUs", "uplink": "uplink traffic"}
    return f"{label.get(what, what)} on {node} over by {value * 100:.0f}%"


def _gpu_shortfall(problem: Problem) -> str:
    """The fleet's GPU shortfall, when its GPU modules need more GPUs in all than every node
    they may use has (after what the robots hold for fallbacks): no plan can fit them, and
    the nodes one plan overfills are only where that plan put the excess."""
    needy = np.flatnonzero((problem.gpu > 0) & problem.allowed.any(axis=1))
    if not needy.size:
        return ""
    nodes = np.flatnonzero(problem.allowed[needy].any(axis=0))
    have = problem.capacity[nodes, 2] - problem.fallback_reserve(problem.limits)[nodes, 2]
    have = np.maximum(have, 0.0)
    need = float(problem.gpu[needy].sum())
    if need <= float(have.sum()) + 1e-9:
        return ""
    modules = sorted({problem.instances[int(i)].module for i in needy})
    with_gpu = [
        f"{problem.nodes[int(j)].name} {h:g}" for j, h in zip(nodes, have, strict=True) if h
    ]
    where = (
        f" ({', '.join(with_gpu[:6])}{', ...' if len(with_gpu) > 6 else ''})" if with_gpu else ""
    )
    return (
        f"the fleet needs {need:g} GPUs in all ({len(needy)} instance(s) of "
        f"{', '.join(modules)}) but the nodes they may use have {float(have.sum()):g}{where}: "
        f"{need - float(have.sum()):g} GPU(s) short"
    )


def _reserve_note(problem: Problem) -> str:
    """What the robots hold for on-board fallbacks (issue 13), when they hold anything."""
    rows = problem.fallback_rows
    if not rows.size:
        return ""
    reserve = problem.fallback_reserve(problem.limits)[:, 0]
    robots = np.flatnonzero(reserve > 0)
    modules = sorted({problem.instances[i].module for i in rows})
    each = ", ".join(
        f"{problem.nodes[r].name} {format_cores(float(reserve[r]))}" for r in robots[:4]
    )
    more = f" and {len(robots) - 4} more robots" if len(robots) > 4 else ""
    return (
        f" (CPU held for on-board fallbacks of {', '.join(modules)}: {each}{more}; a module "
        "with fallback.mode onboard keeps its on-board share on its robot wherever it runs, "
        "one with mode variant its variant's; a smaller fallback.cpu or a lighter variant "
        "holds less)"
    )


def _amount(resource: str, value: float) -> str:
    if resource == "memory":
        return f"{value / 2**30:.1f}Gi"
    if resource == "cpu":
        return format_cores(value)
    return f"{value:g}"


def degraded_message(problem: Problem, x: np.ndarray) -> str:
    """Which modules a degraded plan runs below the CPU their deadline needs: how many
    instances, on which nodes, the CPU they get instead of what they need, their priority and
    the misses predicted for them (``module_miss_rates``)."""
    if not problem.degraded or problem.levels is None or problem.ladder is None:
        return "not degraded"
    rates = module_miss_rates(problem, x, True)
    lad = problem.ladder
    by_module: dict[str, list[int]] = {}
    for n in np.flatnonzero(problem.levels > 0):
        by_module.setdefault(problem.instances[int(n)].module, []).append(int(n))
    parts = []
    for module, idx in sorted(by_module.items(), key=lambda kv: -rates.get(kv[0], 0.0)):
        i = idx[0]
        j = int(x[i])
        k = min(int(problem.levels[i]), int(lad.depth[i, j]))
        prio = int(problem.priority[i]) if problem.priority is not None else 0
        nodes = sorted({problem.nodes[int(x[n])].name for n in idx})
        parts.append(
            f"{module} x{len(idx)} on {', '.join(nodes[:3])}{'...' if len(nodes) > 3 else ''} "
            f"requests {format_cores(float(lad.cpu[i, j, k]))} cpu of the "
            f"{format_cores(float(lad.cpu[i, j, 0]))} its deadline needs (its limit: it bursts "
            f"when the node has idle CPU; priority {prio}, predicted miss "
            f"{format_miss_rate(rates.get(module, 0.0))})"
        )
    total = sum(len(v) for v in by_module.values())
    return (
        f"degraded: the nodes are short of CPU, so {total} instance(s) of the lowest-priority "
        f"modules run below the CPU their deadline needs: " + "; ".join(parts)
    )
