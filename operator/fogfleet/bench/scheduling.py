"""Scheduling benchmark rows (pure functions; the CLI's ``fogfleet bench scheduling`` prints them).

(a) ``optimality_gap``: nsga2's best plan on its front vs the exact MILP optimum of the same
    scalar S (exact.py) on the warehouse fleet, over several seeds.
(b) ``decision_time``: wall time of ``plan`` on the warehouse fleet (median of repeats) and on
    a generated fleet (``synthetic_fleet``: 100 robots x 8 modules on 40 edge nodes).
(c) ``standin``: the paper's plain NSGA-II (random sampling, no repair, penalty only,
    single-point crossover, 30 % per-gene mutation) vs ours, at ~1000 genes and on the
    warehouse fleet: feasible?, S and its gap to the MILP optimum or to the LP bound.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fogfleet.api.loader import Catalog, load_paths
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerSettings
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.scheduling.exact import scalarised, solve_exact
from fogfleet.scheduling.schedule import Schedule
from fogfleet.scheduling.solver import nsga2, plan

__all__ = [
    "WAREHOUSE",
    "decision_time",
    "format_table",
    "optimality_gap",
    "standin",
    "synthetic_fleet",
    "warehouse_problem",
]

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
Row = dict[str, Any]


def warehouse_problem(examples: Path = WAREHOUSE) -> Problem:
    cat = load_paths([str(examples)])
    return build_problem(cat.fleets[0], cat)


def synthetic_fleet(
    robots: int, edges: int, seed: int, examples: Path = WAREHOUSE
) -> tuple[Catalog, RobotFleet]:
    """A larger warehouse: ``robots`` copies of the warehouse robot, ``edges`` edge nodes of
    the warehouse's two VM series (D*s v3: 4 GiB/core, speed 1; F*s v2: 2 GiB/core, speed
    1.25), the same 8 modules. 40 warehouse-sized edges (8 or 16 cores) cannot host the
    off-board demand of 100 robots (with the limits allocation a robot needs >= 8.75 cores
    off board, its own computer has 6), so edge sizes are drawn from the series' 8-64 core
    sizes with a mean of 12 cores per robot per edge-robot ratio, as in the warehouse
    (72 edge cores for 5 robots)."""
    base = load_paths([str(examples)])
    fleet0 = base.fleets[0]
    robot_t = base.nodes[fleet0.spec.robots[0]]
    series: dict[str, ComputeNode] = {}
    for name in fleet0.spec.nodes:
        nd = base.nodes[name]
        series.setdefault(nd.spec.hardware_type.split("-")[0], nd)
    rng = np.random.default_rng(seed)
    cat = Catalog(modules=dict(base.modules))
    robot_names = [f"robot-{k + 1:03d}" for k in range(robots)]
    for name in robot_names:
        cat.add(
            robot_t.model_copy(
                update={"metadata": robot_t.metadata.model_copy(update={"name": name})}
            )
        )
    target = 12.0 * robots / max(edges, 1)
    sizes = [8, 16, 32, 64]
    lo = max([s for s in sizes if s <= target], default=8)
    hi = min([s for s in sizes if s >= target], default=64)
    p_hi = 0.0 if hi == lo else (target - lo) / (hi - lo)
    edge_names = [f"edge-{k + 1:03d}" for k in range(edges)]
    kinds = sorted(series)
    for name in edge_names:
        kind = kinds[int(rng.integers(len(kinds)))]
        tmpl = series[kind]
        cores = hi if rng.random() < p_hi else lo
        assert tmpl.spec.capacity is not None
        gib_per_core = 4 if kind.startswith("dsv3") else 2
        cap = tmpl.spec.capacity.model_copy(
            update={"cpu": cores, "memory": f"{cores * gib_per_core}Gi"}
        )
        spec = tmpl.spec.model_copy(update={"capacity": cap, "hardware_type": f"{kind}-{cores}"})
        cat.add(
            tmpl.model_copy(
                update={"metadata": tmpl.metadata.model_copy(update={"name": name}), "spec": spec}
            )
        )
    fspec = fleet0.spec.model_copy(update={"robots": robot_names, "nodes": edge_names})
    fleet = fleet0.model_copy(
        update={
            "metadata": fleet0.metadata.model_copy(update={"name": f"synthetic-{robots}x{edges}"}),
            "spec": fspec,
        }
    )
    cat.add(fleet)
    return cat, fleet


def _best_on_front(problem: Problem, s: Schedule) -> float:
    plans = s.pareto_placements if s.pareto_placements is not None else s.placement[None, :]
    return min(scalarised(problem, x) for x in plans)


def optimality_gap(
    seeds: Sequence[int] = (1, 2, 3, 4, 5), problem: Problem | None = None
) -> list[Row]:
    """(a) nsga2 (default settings) vs the MILP optimum of S, one row per seed; beside it the
    gap when every generation runs (``stallGenerations: 0``): what stopping early costs."""
    p = problem or warehouse_problem()
    t0 = time.perf_counter()
    ex = solve_exact(p)
    t_exact = time.perf_counter() - t0
    opt = scalarised(p, ex.placement)
    rows: list[Row] = []
    for seed in seeds:
        s = plan(p, SchedulerSettings(seed=seed))
        best = _best_on_front(p, s)
        every = _best_on_front(p, plan(p, SchedulerSettings(seed=seed, stall_generations=0)))
        rows.append(
            {
                "bench": "gap",
                "fleet": p.fleet,
                "seed": seed,
                "feasible": s.feasible,
                "nsga2_S": round(best, 5),
                "chosen_S": round(scalarised(p, s.placement), 5),
                "exact_S": round(opt, 5),
                "gap_pct": round(100 * (best - opt) / opt, 2),
                "generations": s.generations,
                "gap_every_generation_pct": round(100 * (every - opt) / opt, 2),
                "nsga2_s": round(s.duration_seconds, 2),
                "exact_s": round(t_exact, 2),
            }
        )
    return rows


def decision_time(repeats: int = 5, robots: int = 100, edges: int = 40, seed: int = 1) -> list[Row]:
    """(b) plan() wall time: the warehouse (median of ``repeats``) with the default stall rule
    and with every generation run (``stallGenerations: 0``), interleaved so both see the same
    machine; then the synthetic fleet (once)."""
    p = warehouse_problem()
    variants = {"default": None, "every generation": 0}
    runs: dict[str, list[Schedule]] = {name: [] for name in variants}
    for _ in range(repeats):
        for name, stall in variants.items():
            runs[name].append(plan(p, SchedulerSettings(seed=seed, stall_generations=stall)))
    rows: list[Row] = [
        {
            "bench": "time",
            "fleet": f"{p.fleet} ({name})",
            "genes": p.n_instances,
            "nodes": p.n_nodes,
            "median_s": round(statistics.median(s.duration_seconds for s in done), 2),
            "runs": repeats,
            "feasible": all(s.feasible for s in done),
            "generations": done[-1].generations,
            "missRate": done[-1].objectives["missRate"],
        }
        for name, done in runs.items()
    ]
    cat, fleet = synthetic_fleet(robots, edges, seed)
    q = build_problem(fleet, cat)
    s = plan(q, SchedulerSettings(seed=seed, time_budget_millis=30000))
    rows.append(
        {
            "bench": "time",
            "fleet": q.fleet,
            "genes": q.n_instances,
            "nodes": q.n_nodes,
            "median_s": round(s.duration_seconds, 2),
            "runs": 1,
            "feasible": s.feasible,
            "generations": s.generations,
            "missRate": s.objectives["missRate"],
        }
    )
    return rows


def _compare(p: Problem, seed: int, opt: float, bound_kind: str, budget_ms: int) -> list[Row]:
    rows: list[Row] = []
    settings = SchedulerSettings(seed=seed, time_budget_millis=budget_ms)
    for name, paper in (("paper-nsga2", True), ("fogfleet-nsga2", False)):
        s = nsga2(p, settings, paper=paper)
        best = _best_on_front(p, s) if s.feasible else float("nan")
        rows.append(
            {
                "bench": "standin",
                "fleet": p.fleet,
                "genes": p.n_instances,
                "variant": name,
                "feasible": s.feasible,
                "S": round(best, 5),
                bound_kind: round(opt, 5),
                "gap_pct": round(100 * (best - opt) / opt, 2) if s.feasible else float("nan"),
                "seconds": round(s.duration_seconds, 2),
                "generations": s.generations,
            }
        )
    return rows


def standin(robots: int = 125, edges: int = 50, seed: int = 1) -> list[Row]:
    """(c) the paper's plain NSGA-II vs ours: on the warehouse fleet (gap to the MILP optimum)
    and at robots * 8 genes (gap to the LP-relaxation lower bound, an upper bound on the true
    gap)."""
    p = warehouse_problem()
    rows = _compare(p, seed, scalarised(p, solve_exact(p).placement), "exact_S", 20000)
    cat, fleet = synthetic_fleet(robots, edges, seed)
    q = build_problem(fleet, cat)
    lb = solve_exact(q, relax=True).value
    rows += _compare(q, seed, lb, "lp_bound_S", 60000)
    return rows


def format_table(rows: Sequence[Row]) -> str:
    """A plain-text table of benchmark rows (columns: union of keys, in first-seen order)."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    cells = [[str(r.get(c, "")) for c in cols] for r in rows]
    widths = [
        max(len(c), *(len(row[k]) for row in cells)) if cells else len(c)
        for k, c in enumerate(cols)
    ]
    line = "  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(out)
