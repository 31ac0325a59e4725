"""Objectives and constraints of a placement, vectorised over a population of plans.

Every function takes ``(problem, X, allocation)`` where ``X`` is a ``(P, I)`` integer array of
node indices (one row per plan, one column per instance; ``-1`` means "not placed": such an
instance contributes nothing) and returns ``(P,)`` values to be minimised. Per-node sums use one
``np.bincount`` over the flattened population (offset ``p * N``), so there is no Python loop over
plans. ``evaluate`` shares the intermediate arrays between objectives.

The per-node load model they share is ``evaluation.Evaluation``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.robotfleet import ObjectiveName
from fogfleet.domain.problem import Allocation, Problem

from .evaluation import NODE_SUMS, UPLINK_SHARE, Evaluation, miss_probability

__all__ = [
    "EVALUATORS",
    "NODE_OBJECTIVES",
    "NODE_SUMS",
    "OBJECTIVES",
    "UPLINK_SHARE",
    "Evaluation",
    "balance",
    "constraint_names",
    "constraints",
    "cost",
    "energy",
    "evaluate",
    "migrations",
    "missRate",
    "miss_probability",
    "missedCycles",
    "module_miss_rates",
    "onboard",
    "reserve",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def onboard(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """F1 (eq. 1): on-board resource use, sum over robot nodes j and r in {cpu, memory} of
    u_j^r / L_j^r, with u^cpu = sum activation * cpu_use (expected use) and u^mem the requested
    bytes. Dividing by the node's own limit makes cores and bytes summable; the paper sums raw
    usage, which would let bytes swamp cores."""
    return Evaluation(problem, X, allocation).onboard()


def reserve(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """F2 (eq. 2, garbled in the paper: "u_j^r - sum L_j^r"). Our reading of "maintain a certain
    resource reserve": the peak requested utilisation max_{j,r} u_j^r / L_j^r over all nodes
    and resources (cpu requests, memory, gpu); minimising it maximises the smallest reserve."""
    return Evaluation(problem, X, allocation).reserve()


def balance(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """F3 (eq. 3): sum over resources of the standard deviation of the utilisation
    u_j^r / L_j^r (cpu: expected use as in F1; memory: requested; gpu if any node of the tier
    has one), taken within each tier (edge, cloud) and summed: the paper's C_E spans edge and
    cloud, which rewards filling a paid cloud. A tier with fewer than two nodes adds 0."""
    return Evaluation(problem, X, allocation).balance()


def missedCycles(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """F4 (eq. 5-6): sum_i activation_i * tau_>1(i, x_i), tau = t_cycle / t_expected with
    t_cycle = net_mean + exe_mean * kappa_j (eq. 4) and kappa_j = max(1, load_j / cap_j) the
    CPU contention of the node (load = sum of activation * cpu_use of its instances)."""
    return Evaluation(problem, X, allocation).missed_cycles()


def missRate(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """Predicted miss rate of the fleet: the mean over modules of each module's predicted
    share of missed cycles, sum_i a_i P(t_cycle_i > T_i) / sum_i a_i over its instances
    (``Evaluation.miss_rate``; the simulator's figure is defined the same way).

    t_cycle is normal with mean net_mean + exe_mean * k and std sqrt((exe_std k)^2 +
    net_std^2). The slowdown k = max(1, D / cap) is overlap-aware: D, the CPU demand on the
    node while the cycle executes, counts every other instance there with the probability
    that it is executing too (activation x duty cycle), and the miss probability is averaged
    over D by Gauss-Hermite quadrature (``Evaluation.overlap_demand``). A node whose
    all-active peak fits its capacity (always so for a feasible ``limits`` plan) has k = 1."""
    return Evaluation(problem, X, allocation).miss_rate()


def cost(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """Extension (III-D's "economic cost"): sum_j cost_per_core_hour_j * requested cores_j."""
    return Evaluation(problem, X, allocation).cost()


def energy(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """Extension: robot power in W, sum over robots of idle + per_core * expected on-board CPU
    use + radio * offloaded Mbps (problem.power)."""
    return Evaluation(problem, X, allocation).energy()


def migrations(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """Extension (issue 10): how many running instances the plan moves to another node; listed
    in ``scheduler.objectives``, a re-plan trades moves against the other objectives."""
    return Evaluation(problem, X, allocation).migrations()


def constraints(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """Hard constraints G (P, 3N + N_R + 1), feasible where every entry <= 0: per node
    (cpu requests, memory, gpus - capacity) / capacity; per robot (off-board traffic -
    80% uplink) / (80% uplink); and the number of genes outside their gene space."""
    return Evaluation(problem, X, allocation).constraints()


def constraint_names(problem: Problem) -> list[str]:
    """Column labels of ``constraints``."""
    names = [f"{r}:{nd.name}" for r in ("cpu", "memory", "gpu") for nd in problem.nodes]
    names += [f"uplink:{problem.nodes[j].name}" for j in np.flatnonzero(problem.tier == 0)]
    return [*names, "geneSpace"]


# The API's ObjectiveName is the registry; every objective the CRD accepts is evaluated here.
EVALUATORS: dict[str, Callable[[Evaluation], F64]] = {
    ObjectiveName.ONBOARD.value: Evaluation.onboard,
    ObjectiveName.RESERVE.value: Evaluation.reserve,
    ObjectiveName.BALANCE.value: Evaluation.balance,
    ObjectiveName.MISSED_CYCLES.value: Evaluation.missed_cycles,
    ObjectiveName.MISS_RATE.value: Evaluation.miss_rate,
    ObjectiveName.COST.value: Evaluation.cost,
    ObjectiveName.ENERGY.value: Evaluation.energy,
    ObjectiveName.MIGRATIONS.value: Evaluation.migrations,
}

# The per-node objectives: what ``Evaluation.of_node_sums`` supports (from ``NODE_SUMS``).
NODE_OBJECTIVES = ("onboard", "reserve", "balance", "cost", "energy")

OBJECTIVES: dict[str, Callable[[Problem, NDArray[np.integer], Allocation], F64]] = {
    ObjectiveName.ONBOARD.value: onboard,
    ObjectiveName.RESERVE.value: reserve,
    ObjectiveName.BALANCE.value: balance,
    ObjectiveName.MISSED_CYCLES.value: missedCycles,
    ObjectiveName.MISS_RATE.value: missRate,
    ObjectiveName.COST.value: cost,
    ObjectiveName.ENERGY.value: energy,
    ObjectiveName.MIGRATIONS.value: migrations,
}


def evaluate(
    problem: Problem,
    X: NDArray[np.integer],
    allocation: Allocation,
    names: Sequence[str] = tuple(OBJECTIVES),
) -> dict[str, F64]:
    """The named objectives of every plan in X, sharing intermediate arrays."""
    ev = Evaluation(problem, X, allocation)
    unknown = [n for n in names if n not in EVALUATORS]
    if unknown:
        raise KeyError(f"unknown objective(s): {', '.join(unknown)}")
    return {n: EVALUATORS[n](ev) for n in names}


def module_miss_rates(
    problem: Problem, x: NDArray[np.integer], with_limits: bool
) -> dict[str, float]:
    """The predicted miss rate of each module of one plan ``x`` (I,): the activation-weighted
    mean over its placed instances of ``missRate``'s per-instance prediction; the fleet's
    ``missRate`` is the mean of these rates."""
    ev = Evaluation(
        problem, np.asarray(x, dtype=np.int64)[None, :], problem.allocation(with_limits)
    )
    p = ev.instance_miss()[0]
    a = np.where(ev.valid[0], problem.activation, 0.0)
    out: dict[str, float] = {}
    for name in sorted({inst.module for inst in problem.instances}):
        idx = [i for i, inst in enumerate(problem.instances) if inst.module == name]
        weight = float(a[idx].sum())
        if weight > 0:
            out[name] = float((a[idx] * p[idx]).sum() / weight)
    return out
