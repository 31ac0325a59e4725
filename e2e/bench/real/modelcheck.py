"""What the model predicts for the paper bed before anything runs (issue 33's model check).

    python -m e2e.bench.real.modelcheck [--orders 12] [--seeds 6]

Offline, on the benchmark's own fleet (``scenario.Scenario``): nsga2 planned with each of the
bench's seeds, and kube-scheduler's default placement (``scheduling.baselines.k8s_default``)
with the pods reaching the scheduler in ``--orders`` creation orders (the fleet's own, then
random permutations: on a cluster the order varies with the controllers' timing), each
simulated for the bench's window with every module active. It prints the primary endpoint
(perception, pooled) and the all-modules mean per plan and their medians, and the cores each
plan keeps busy on average (uncontended), so the bed can be judged before its first
measurement.
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Sequence

import numpy as np

from e2e.bench.real.protocol import PERCEPTION, Protocol
from e2e.bench.real.scenario import Scenario
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.baselines import k8s_default
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import plan
from fogfleet.sim import simulate

__all__ = ["Predicted", "main", "predict"]

Predicted = tuple[str, float, float, float]  # (label, perception, all modules, mean cores)


def _simulated(
    problem: Problem, sched: Schedule, seconds: float, seed: int
) -> tuple[float, float, float]:
    p = problem.with_levels(sched.levels)
    r = simulate(
        p, sched.placement, p.allocation(sched.with_limits), seconds, seed, all_active=True
    )
    missed = sum(r.module_miss_rate[m] * r.module_cycles[m] for m in PERCEPTION)
    cycles = sum(r.module_cycles[m] for m in PERCEPTION)
    # the cores the plan keeps busy on average: each instance's CPU for its share of a cycle
    i = np.flatnonzero(sched.placement >= 0)
    j = sched.placement[i]
    alloc = p.allocation(sched.with_limits)
    busy = np.minimum(1.0, alloc.exe_mean[i, j] / p.cycle[i])
    return missed / cycles, r.miss_rate, float((alloc.cpu_use[i, j] * busy).sum())


def predict(orders: int = 12, seeds: int = 6, seconds: float | None = None) -> list[Predicted]:
    """One row per plan: nsga2 with seeds 1..``seeds``, kube-scheduler in ``orders`` orders."""
    problem = Scenario().problem
    window = seconds if seconds is not None else Protocol().window_s
    rows: list[Predicted] = []
    for seed in range(1, seeds + 1):
        sched = plan(problem, SchedulerSettings(algorithm="nsga2", seed=seed))
        rows.append((f"nsga2 seed {seed}", *_simulated(problem, sched, window, seed)))
    rng = np.random.default_rng(0)
    for k in range(orders):
        order = np.arange(problem.n_instances) if k == 0 else rng.permutation(problem.n_instances)
        sched = k8s_default(problem, seed=k + 1, order=order)
        label = "k8s-default, fleet order" if k == 0 else f"k8s-default, order {k}"
        rows.append((label, *_simulated(problem, sched, window, k + 1)))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.real.modelcheck", description=__doc__)
    ap.add_argument("--orders", type=int, default=12, help="kube-scheduler creation orders")
    ap.add_argument("--seeds", type=int, default=6, help="nsga2 seeds")
    ns = ap.parse_args(argv)
    rows = predict(ns.orders, ns.seeds)
    print(f"{'PLAN':<28} {'PERCEPTION':>10} {'ALL MODULES':>11} {'MEAN CORES':>10}")
    for label, perception, overall, cores in rows:
        print(f"{label:<28} {perception:>10.2%} {overall:>11.2%} {cores:>10.3f}")
    for arm in ("nsga2", "k8s-default"):
        mine = [r for r in rows if r[0].startswith(arm)]
        print(
            f"{arm} median: perception {statistics.median(r[1] for r in mine):.2%} "
            f"(range {min(r[1] for r in mine):.2%}-{max(r[1] for r in mine):.2%}), "
            f"all modules {statistics.median(r[2] for r in mine):.2%}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
