"""Objectives and constraints of a placement, vectorised over a population of plans.

Every function takes ``(problem, X, allocation)`` where ``X`` is a ``(P, I)`` integer array of
node indices (one row per plan, one column per instance; ``-1`` means "not placed": such an
instance contributes nothing) and returns ``(P,)`` values to be minimised. Per-node sums use one
``np.bincount`` over the flattened population (offset ``p * N``), so there is no Python loop over
plans. ``evaluate`` shares the intermediate arrays between objectives.

The per-node load model they share is ``evaluation.Evaluation``. ``REGISTRY`` pairs each
objective of the API's registry (``api.v1alpha1.objectives``: name, label, unit, direction,
resolution) with its functions; every other table of objectives is read from it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.objectives import (
    OBJECTIVE_SPECS,
    Direction,
    ObjectiveName,
    ObjectiveSpec,
)
from fogfleet.domain.problem import Allocation, Problem

from .evaluation import NODE_SUMS, UPLINK_SHARE, Evaluation, miss_probability

__all__ = [
    "EVALUATORS",
    "NODE_OBJECTIVES",
    "NODE_SUMS",
    "OBJECTIVES",
    "REGISTRY",
    "UPLINK_SHARE",
    "Evaluation",
    "Objective",
    "balance",
    "constraint_names",
    "constraints",
    "cost",
    "energy",
    "evaluate",
    "feasible",
    "migrations",
    "missRate",
    "miss_probability",
    "missedCycles",
    "module_miss_rates",
    "objective_values",
    "onboard",
    "reserve",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def onboard(problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> F64:
    """F1 (eq. 1): on-board resource use, sum over robot nodes j and r in {cpu, memory} of
    u_j^r / L_j^r, with u^cpu = sum activation * cpu_use (expected use) and u^mem the requested
    bytes. Dividing by the node's own limit makes cores and bytes summable; the paper sums raw
    usage, which would let bytes swamp cores. CPU a module's on-board standby already holds on
    its robot is not counted again when the module runs there (``Evaluation.cpu_onboard``), as
    memory's held share is not: that use is the robot's whatever the plan."""
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


def objective_values(
    problem: Problem, x: NDArray[np.integer], with_limits: bool, names: Sequence[str]
) -> dict[str, float]:
    """The named objectives of one plan ``x`` (I,) under the limits or nominal allocation."""
    out = evaluate(
        problem,
        np.asarray(x, dtype=np.int64)[None, :],
        problem.allocation(with_limits),
        list(names),
    )
    return {k: float(v[0]) for k, v in out.items()}


def feasible(problem: Problem, x: NDArray[np.integer], with_limits: bool = True) -> bool:
    """Every hard constraint of the plan holds (capacity, uplink, gene spaces)."""
    g = constraints(
        problem, np.asarray(x, dtype=np.int64)[None, :], problem.allocation(with_limits)
    )
    return bool(np.all(g <= 1e-9))


def constraint_names(problem: Problem) -> list[str]:
    """Column labels of ``constraints``."""
    names = [f"{r}:{nd.name}" for r in ("cpu", "memory", "gpu") for nd in problem.nodes]
    names += [f"uplink:{problem.nodes[j].name}" for j in np.flatnonzero(problem.tier == 0)]
    return [*names, "geneSpace"]


ObjectiveFunction = Callable[[Problem, NDArray[np.integer], Allocation], F64]


@dataclass(frozen=True)
class Objective:
    """One objective of the registry: what it measures (``ObjectiveSpec``: name, label, unit,
    direction, resolution) and how it is computed, from a shared ``Evaluation`` (``of``) or
    standalone (``function``)."""

    spec: ObjectiveSpec
    of: Callable[[Evaluation], F64]
    function: ObjectiveFunction
    per_node: bool = False  # follows from per-node sums alone (``Evaluation.of_node_sums``)

    @property
    def name(self) -> str:
        return self.spec.name.value


def _objective(
    name: ObjectiveName, of: Callable[[Evaluation], F64], fn: ObjectiveFunction, per_node: bool
) -> tuple[str, Objective]:
    return name.value, Objective(OBJECTIVE_SPECS[name.value], of, fn, per_node)


# The registry: every objective the API accepts (``api.v1alpha1.objectives``), with its functions.
REGISTRY: dict[str, Objective] = dict(
    [
        _objective(ObjectiveName.ONBOARD, Evaluation.onboard, onboard, True),
        _objective(ObjectiveName.RESERVE, Evaluation.reserve, reserve, True),
        _objective(ObjectiveName.BALANCE, Evaluation.balance, balance, True),
        _objective(ObjectiveName.MISSED_CYCLES, Evaluation.missed_cycles, missedCycles, False),
        _objective(ObjectiveName.MISS_RATE, Evaluation.miss_rate, missRate, False),
        _objective(ObjectiveName.COST, Evaluation.cost, cost, True),
        _objective(ObjectiveName.ENERGY, Evaluation.energy, energy, True),
        _objective(ObjectiveName.MIGRATIONS, Evaluation.migrations, migrations, False),
    ]
)
if list(REGISTRY) != list(OBJECTIVE_SPECS):  # pragma: no cover - a programming error
    raise RuntimeError("scheduling.objectives.REGISTRY must cover OBJECTIVE_SPECS, in order")
if any(o.spec.direction is not Direction.MINIMISE for o in REGISTRY.values()):  # pragma: no cover
    raise RuntimeError("the search minimises: negate an objective to maximise in its function")

# Views of the registry for the callers that want one column of it.
EVALUATORS: dict[str, Callable[[Evaluation], F64]] = {n: o.of for n, o in REGISTRY.items()}
OBJECTIVES: dict[str, ObjectiveFunction] = {n: o.function for n, o in REGISTRY.items()}
# The per-node objectives: what ``Evaluation.of_node_sums`` supports (from ``NODE_SUMS``).
NODE_OBJECTIVES: tuple[str, ...] = tuple(n for n, o in REGISTRY.items() if o.per_node)


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
    problem: Problem,
    x: NDArray[np.integer],
    with_limits: bool,
    allocation: Allocation | None = None,
) -> dict[str, float]:
    """The predicted miss rate of each module of one plan ``x`` (I,): the activation-weighted
    mean over its placed instances of ``missRate``'s per-instance prediction; the fleet's
    ``missRate`` is the mean of these rates. ``allocation``: the CPU the plan runs with, when
    it is not the problem's own (a degraded plan's, one under learnt corrections)."""
    given = allocation if allocation is not None else problem.allocation(with_limits)
    ev = Evaluation(problem, np.asarray(x, dtype=np.int64)[None, :], given)
    p = ev.instance_miss()[0]
    a = np.where(ev.valid[0], problem.activation, 0.0)
    out: dict[str, float] = {}
    for name in sorted({inst.module for inst in problem.instances}):
        idx = [i for i, inst in enumerate(problem.instances) if inst.module == name]
        weight = float(a[idx].sum())
        if weight > 0:
            out[name] = float((a[idx] * p[idx]).sum() / weight)
    return out
