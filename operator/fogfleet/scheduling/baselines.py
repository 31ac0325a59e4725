"""Baseline planners: everything on board, kube-scheduler's default scoring, random.

``k8s_default`` emulates kube-scheduler (pkg/scheduler/framework/plugins/noderesources in
kubernetes/kubernetes) placing the pods of a set of single-replica Deployments one by one, in
the order they are created (``problem.instances``: module by module, robot by robot):

- Filter: NodeResourcesFit (pod requests, cpu and memory, plus gpu as an extended resource,
  fit into allocatable minus the requests already bound) and the required node affinity we
  render (the gene space ``problem.allowed``).
- Score (default plugin weights 1 + 1; all other default score plugins give every node of
  our clusters the same score): NodeResourcesFit with the LeastAllocated strategy,
  ``leastRequestedScore = (allocatable - requested) * 100 / allocatable`` per resource in
  integer arithmetic (millicores, bytes), averaged over cpu and memory with weights 1
  (least_allocated.go), and NodeResourcesBalancedAllocation, ``int((1 - std) * 100)`` where
  std = |f_cpu - f_mem| / 2 of the requested fractions f = requested / allocatable capped at
  1 (balanced_allocation.go). "requested" includes the incoming pod (resource_allocation.go).
- The highest total wins; ties are broken uniformly at random (selectHost's reservoir
  sampling), here with ``numpy.random.default_rng(seed)``. Every node is scored: the gene
  spaces have fewer than 100 feasible nodes, below percentageOfNodesToScore's floor.

Pods get their nominal requests and no limit (``problem.nominal``), as a plain Deployment.
A pod that fits nowhere stays Pending (placement -1).
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Problem

from .objectives import constraints, evaluate
from .operators import repair_plans
from .problem import PlacementProblem
from .schedule import Schedule

__all__ = ["finish", "k8s_default", "k8s_scores", "onboard_plan", "random_plan"]

I64 = NDArray[np.int64]


def finish(
    problem: Problem,
    name: str,
    x: I64,
    with_limits: bool,
    t0: float,
    reason: str,
    extra_reasons: dict[int, str] | None = None,
) -> Schedule:
    """Wrap a plan into a Schedule with every objective and feasibility evaluated."""
    alloc = problem.allocation(with_limits)
    vals = evaluate(problem, x[None, :], alloc)
    g = constraints(problem, x[None, :], alloc)[0]
    reasons = dict(problem.reasons)
    reasons.update(extra_reasons or {})
    feasible = bool(np.all(g <= 1e-9)) and not bool((x < 0).any())
    return Schedule(
        scheduler=name,
        placement=x.astype(np.int64),
        with_limits=with_limits,
        objectives={k: float(v[0]) for k, v in vals.items()},
        feasible=feasible,
        duration_seconds=time.perf_counter() - t0,
        choice_reason=reason,
        reasons=reasons,
    )


def onboard_plan(problem: Problem) -> Schedule:
    """Every instance on its home robot (if its gene space allows it, else its first allowed
    node); shared replicas on their first allowed node. Nominal allocation."""
    t0 = time.perf_counter()
    x = np.full(problem.n_instances, -1, dtype=np.int64)
    for i in range(problem.n_instances):
        h = int(problem.home[i])
        if h >= 0 and problem.allowed[i, h]:
            x[i] = h
        elif problem.allowed[i].any():
            x[i] = int(np.argmax(problem.allowed[i]))
    return finish(problem, "onboard", x, False, t0, "every instance on its own robot")


def k8s_scores(
    alloc_cpu_m: NDArray[np.int64],
    alloc_mem: NDArray[np.int64],
    req_cpu_m: NDArray[np.int64],
    req_mem: NDArray[np.int64],
) -> NDArray[np.int64]:
    """LeastAllocated + BalancedAllocation score per node; ``req_*`` already include the pod."""

    def least(req: NDArray[np.int64], cap: NDArray[np.int64]) -> NDArray[np.int64]:
        s = np.where(cap > 0, ((cap - req) * 100) // np.maximum(cap, 1), 0)
        return np.where(req > cap, 0, s).astype(np.int64)

    fit = (least(req_cpu_m, alloc_cpu_m) + least(req_mem, alloc_mem)) // 2
    f_cpu = np.minimum(req_cpu_m / np.maximum(alloc_cpu_m, 1), 1.0)
    f_mem = np.minimum(req_mem / np.maximum(alloc_mem, 1), 1.0)
    balanced = ((1.0 - np.abs(f_cpu - f_mem) / 2.0) * 100.0).astype(np.int64)
    return np.asarray(fit + balanced, dtype=np.int64)


def k8s_default(
    problem: Problem, seed: int = 1, order: NDArray[np.int64] | None = None
) -> Schedule:
    """kube-scheduler's default placement of the fleet's pods (see the module docstring);
    ``order``: the instances in the order their pods reach the scheduler, if not the
    fleet's own (a real cluster's order varies with the controllers' timing)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    alloc_cpu = np.round(problem.capacity[:, 0] * 1000).astype(np.int64)
    alloc_mem = np.round(problem.capacity[:, 1]).astype(np.int64)
    alloc_gpu = np.round(problem.capacity[:, 2]).astype(np.int64)
    used_cpu = np.zeros(problem.n_nodes, dtype=np.int64)
    used_mem = np.zeros(problem.n_nodes, dtype=np.int64)
    used_gpu = np.zeros(problem.n_nodes, dtype=np.int64)
    x = np.full(problem.n_instances, -1, dtype=np.int64)
    pending: dict[int, str] = {}
    for i in range(problem.n_instances) if order is None else (int(k) for k in order):
        if not problem.allowed[i].any():
            continue
        cpu = np.round(problem.nominal.cpu_request[i] * 1000).astype(np.int64)  # per node
        cpu = np.where(problem.allowed[i], cpu, int(cpu.max()))
        mem = round(problem.memory[i])
        gpu = round(problem.gpu[i])
        req_cpu, req_mem = used_cpu + cpu, used_mem + mem
        fits = (
            problem.allowed[i]
            & (req_cpu <= alloc_cpu)
            & (req_mem <= alloc_mem)
            & (used_gpu + gpu <= alloc_gpu)
        )
        if not fits.any():
            pending[i] = (
                f"{problem.label(i)}: 0/{int(problem.allowed[i].sum())} nodes are available: "
                "Insufficient resources"
            )
            continue
        score = np.where(fits, k8s_scores(alloc_cpu, alloc_mem, req_cpu, req_mem), -1)
        best = np.flatnonzero(score == score.max())
        j = int(best[rng.integers(len(best))]) if len(best) > 1 else int(best[0])
        x[i] = j
        used_cpu[j] += cpu[j]
        used_mem[j] += mem
        used_gpu[j] += gpu
    return finish(
        problem,
        "k8s-default",
        x,
        False,
        t0,
        "kube-scheduler default scoring (LeastAllocated + BalancedAllocation), "
        "pods in creation order",
        pending,
    )


def random_plan(problem: Problem, seed: int = 1) -> Schedule:
    """Uniform within each gene space, then the capacity repair; limits allocation."""
    t0 = time.perf_counter()
    pp = PlacementProblem(problem, ("missRate",), with_limits=True)
    rng = np.random.default_rng(seed)
    x = pp.full(pp.random_genes(1, rng))
    x = repair_plans(pp, x)[0]
    return finish(
        problem, "random", x, True, t0, "uniform random within gene spaces, repaired for capacity"
    )
