"""``fogfleet plan`` and ``fogfleet simulate``: a fleet's plan from YAML, and the simulated
missed cycles of plans side by side."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.objectives import ObjectiveName
from fogfleet.api.v1alpha1.robotfleet import PLACEMENT_LIST_LIMIT
from fogfleet.commandline import BAD_INPUT, OK
from fogfleet.domain.miss_rates import format_miss_rate, worst_module
from fogfleet.domain.rows import Learnt
from fogfleet.domain.tenancy import Held, claims_of, with_held
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.explain import degraded_message, infeasible_message, unplaced_reasons
from fogfleet.scheduling.objectives import module_miss_rates

from .common import SCHEDULERS, catalog_of, fleets_of, plan_fleet, settings_of, table

__all__ = ["REFERENCES", "cmd_plan", "cmd_simulate", "recorded_placement"]

# The baselines ``simulate --scheduler all`` runs beside the planner: that one of them cannot
# place the fleet (the on-board reference on a site whose robots are too small) is a result
# of the comparison, reported, not an error of the run.
REFERENCES = ("k8s-default", "onboard")
MISS_RATE = ObjectiveName.MISS_RATE.value


def _placement_rows(problem: Any, schedule: Any) -> list[dict[str, Any]]:
    alloc = problem.allocation(schedule.with_limits)
    rows = []
    for i, inst in enumerate(problem.instances):
        j = int(schedule.placement[i])
        rows.append(
            {
                "robot": inst.robot or "-",
                "module": inst.module,
                "replica": inst.replica,
                "node": problem.nodes[j].name if j >= 0 else None,
                "tier": problem.nodes[j].tier.value if j >= 0 else None,
                "cpu": float(alloc.cpu_request[i, j]) if j >= 0 else None,
            }
        )
        if schedule.levels is not None and schedule.levels[i] > 0 and problem.ladder is not None:
            rows[-1]["cpuForDeadline"] = float(problem.ladder.cpu[i, j, 0])
    return rows


def cmd_plan(args: argparse.Namespace) -> int:
    catalog = catalog_of(args.paths)
    out: list[dict[str, Any]] = []
    infeasible = False
    fleets = fleets_of(catalog, args.fleet)
    if len(fleets) > 1:  # one site: each fleet plans into what the earlier ones left
        order = ", ".join(f"{f.metadata.namespace or 'default'}/{f.metadata.name}" for f in fleets)
        print(f"Planning {len(fleets)} fleets as one site, in this order: {order}", file=sys.stderr)
    held: dict[str, Held] = {}
    for fleet in fleets:
        settings = settings_of(fleet, args.scheduler, args.seed, args)
        problem, schedule = plan_fleet(
            fleet, site_catalog(catalog, held), settings, sys.stderr.isatty() and not args.json
        )
        name = f"RobotFleet {fleet.metadata.namespace or 'default'}/{fleet.metadata.name}"
        for node, (cpu, mem) in claims_of(
            problem, schedule.placement, schedule.with_limits
        ).items():
            held[node] = held.get(node, Held()).plus(cpu, mem, name)
        infeasible |= not schedule.feasible
        rows = _placement_rows(problem, schedule)
        doc = {
            "fleet": f"{problem.namespace}/{problem.fleet}",
            "scheduler": schedule.scheduler,
            "feasible": schedule.feasible,
            "degraded": schedule.degraded,
            "withLimits": schedule.with_limits,
            "placement": rows,
            "objectives": schedule.objectives,
            "durationSeconds": round(schedule.duration_seconds, 4),
            "generations": schedule.generations,
            "timeBudgetReached": schedule.time_budget_reached,
            "choiceReason": schedule.choice_reason,
            "unplaced": unplaced_reasons(problem, schedule.reasons),
            "moduleMissRates": module_miss_rates(problem, schedule.placement, schedule.with_limits),
        }
        doc["worstModule"] = worst_module(
            doc["moduleMissRates"], unplaced=_unplaced_modules(problem, schedule.placement)
        )
        if not schedule.feasible:
            doc["infeasible"] = infeasible_message(problem, schedule.placement, schedule.reasons)
        if schedule.degraded:
            doc["degradedReason"] = degraded_message(problem, schedule.placement)
            # a warning people see even with --json on stdout
            print(f"DEGRADED {doc['fleet']}: {doc['degradedReason']}", file=sys.stderr)
        out.append(doc)
        if args.plot:
            from fogfleet.plot import plot_plan

            try:
                plot_plan(problem, schedule, Path(args.plot))
            except OSError as exc:  # a folder that does not exist, say: bad input, exit 2
                raise InvalidSpec(
                    args.plot, "--plot", f"cannot be written: {exc.strerror}"
                ) from exc
        if not args.json:
            _print_plan(doc)
    if args.json:
        print(json.dumps(out[0] if len(out) == 1 else out, indent=2))
    return BAD_INPUT if infeasible else OK


def site_catalog(catalog: Catalog, held: dict[str, Held]) -> Catalog:
    """``catalog`` with each ComputeNode's capacity less what the fleets planned before hold
    on its Node (``domain.tenancy``)."""
    if not held:
        return catalog
    nodes = {name: with_held(cn, held.get(cn.node_name)) for name, cn in catalog.nodes.items()}
    return dataclasses.replace(catalog, nodes=nodes)


def _print_plan(doc: dict[str, Any]) -> None:
    print(
        f"Fleet {doc['fleet']}  scheduler={doc['scheduler']}  feasible={doc['feasible']}  "
        f"degraded={doc['degraded']}  ({doc['durationSeconds']:.2f} s)"
    )
    rows = [
        [
            r["robot"],
            r["module"] + (f"#{r['replica']}" if r["robot"] == "-" else ""),
            r["node"] or "UNPLACED",
            r["tier"] or "-",
            (f"{r['cpu']:g}" if r["cpu"] is not None else "-")
            + (f" (needs {r['cpuForDeadline']:g})" if "cpuForDeadline" in r else ""),
        ]
        for r in doc["placement"]
    ]
    print(table(rows, ["ROBOT", "MODULE", "NODE", "TIER", "CPU"]))
    print()
    print(
        "Objectives: "
        + ", ".join(
            f"{k}={format_miss_rate(v) if k == MISS_RATE else f'{v:.4g}'}"
            for k, v in doc["objectives"].items()
        )
    )
    rates = doc["moduleMissRates"]
    if rates:
        print(
            "Predicted missed cycles per module: "
            + ", ".join(f"{m} {format_miss_rate(r)}" for m, r in sorted(rates.items()))
            + f" (worst: {doc['worstModule']}"
            + (" UNPLACED)" if doc["worstModule"] not in rates else ")")
        )
    if doc["choiceReason"]:
        print(f"Choice: {doc['choiceReason']}")
    for label, why in doc["unplaced"].items():
        print(f"UNPLACED {label}: {why}", file=sys.stderr)
    if "infeasible" in doc:
        print(f"INFEASIBLE {doc['fleet']}: {doc['infeasible']}", file=sys.stderr)


def cmd_simulate(args: argparse.Namespace) -> int:
    from fogfleet.domain.build import build_problem
    from fogfleet.scheduling.solver import plan
    from fogfleet.sim import simulate

    catalog = catalog_of(args.paths)
    fleet = fleets_of(catalog, args.fleet)[0]
    problem = build_problem(fleet, catalog)
    learnt: dict[tuple[str, str], tuple[Learnt, float]] = {}
    if args.from_prometheus:
        from .observed import describe, learnt_corrections

        learnt = learnt_corrections(args.from_prometheus, fleet, catalog, args.window)
        if not args.json:
            print(f"Execution times measured over {args.window} s in {args.from_prometheus}:")
            for line in describe(learnt) or ["none (every plan runs as declared)"]:
                print(f"  {line}")
    factors = {k: f for k, (f, _) in learnt.items()}
    names = (
        list(SCHEDULERS[:3])
        if args.scheduler == "all"
        else [args.scheduler or fleet.spec.scheduler.algorithm]
    )
    placements: dict[str, tuple[Any, Any]] = {}  # name -> (placement, allocation)
    if args.placement:
        placements["recorded"] = _read_placement(problem, Path(args.placement))
    infeasible: list[str] = []  # the planner's: an error (exit 2)
    references: list[str] = []  # a baseline's beside it (--scheduler all): a result
    for name in names:
        settings = settings_of(fleet, str(name), args.seed, args)
        schedule = plan(problem, settings)
        planned = problem.with_levels(schedule.levels)
        placements[str(name)] = (schedule.placement, planned.allocation(schedule.with_limits))
        if not schedule.feasible:
            why = infeasible_message(problem, schedule.placement, schedule.reasons)
            if len(names) > 1 and str(name) in REFERENCES:
                references.append(f"{name} (a reference, compared only): {why}")
            else:
                infeasible.append(f"{name}: {why}")
    if factors:  # what re-planning with the measured profiles would give
        from .observed import under_corrections

        real = build_problem(fleet, catalog, corrections=factors)
        for name in names:
            schedule = plan(real, settings_of(fleet, str(name), args.seed, args))
            planned = real.with_levels(schedule.levels)
            placements[f"{name} re-planned"] = (
                schedule.placement,
                planned.allocation(schedule.with_limits),
            )
        placements = {
            k: (x, a if k.endswith(" re-planned") else under_corrections(problem, a, factors))
            for k, (x, a) in placements.items()
        }
    result: dict[str, Any] = {}
    for name, (placement, allocation) in placements.items():
        sim = simulate(
            problem,
            placement,
            allocation,
            duration_s=args.duration,
            seed=args.seed if args.seed is not None else 0,
            all_active=args.all_active,
        )
        unplaced = _unplaced_modules(problem, placement)
        predicted = module_miss_rates(problem, placement, True, allocation)
        simulated = dict(sim.module_miss_rate)
        result[name] = {
            "missRate": sim.miss_rate,
            "modules": simulated,
            "predicted": predicted,
            "worstModule": worst_module(simulated, predicted, unplaced),
            "unplaced": unplaced,
            "nodeUtilisation": {
                problem.nodes[j].name: u for j, u in enumerate(sim.node_utilisation)
            },
        }
    for line in [*infeasible, *references]:
        print(f"INFEASIBLE {line}", file=sys.stderr)
    if args.json:
        print(json.dumps(result, indent=2))
        return BAD_INPUT if infeasible else OK
    modules = sorted({m for r in result.values() for m in [*r["modules"], *r["unplaced"]]})

    def cell(s: str, m: str) -> str:
        if m in result[s]["unplaced"]:
            return "UNPLACED"
        return format_miss_rate(result[s]["modules"].get(m))  # "-": no cycles

    def overall(s: str) -> str:
        # the fleet's rate covers the modules that ran: beside an unplaced module it would
        # read as a figure for the whole fleet, which nothing simulated
        if result[s]["unplaced"]:
            return f"n/a ({len(result[s]['unplaced'])} unplaced)"
        return format_miss_rate(result[s]["missRate"])

    def worst(s: str) -> str:
        m = result[s]["worstModule"]
        if m is None:
            return "-"
        if m in result[s]["unplaced"]:
            return f"{m} UNPLACED"
        return f"{m} {format_miss_rate(result[s]['modules'].get(m))}"

    rows = [[m, *(cell(s, m) for s in result)] for m in modules]
    rows.append(["OVERALL", *(overall(s) for s in result)])
    rows.append(["WORST MODULE", *(worst(s) for s in result)])
    print(
        f"Missed-cycle rate, fleet {problem.namespace}/{problem.fleet}, "
        f"{args.duration:g} s simulated, seed {args.seed or 0}, "
        + ("all modules active" if args.all_active else "activation rates of the modules")
    )
    print(table(rows, ["MODULE", *result.keys()]))
    return BAD_INPUT if infeasible else OK


def _unplaced_modules(problem: Any, placement: Any) -> list[str]:
    """The modules with an instance ``placement`` leaves unplaced (-1), sorted."""
    return sorted({problem.instances[int(i)].module for i in np.flatnonzero(placement < 0)})


def _read_placement(problem: Any, path: Path) -> tuple[Any, Any]:
    from fogfleet.api.kubeyaml import read_documents

    if not path.is_file():
        raise InvalidSpec(str(path), "", "no such file")
    docs = read_documents(path)  # JSON is YAML too
    return recorded_placement(problem, docs[0] if docs else None, str(path))


def recorded_placement(problem: Any, doc: Any, source: str) -> tuple[Any, Any]:
    """A placement saved by ``fogfleet plan --json`` or read back from a fleet's status (a
    RobotFleet object), and the allocation it ran with (a degraded plan's smaller CPU amounts
    read from its ``cpu``; plain-Deployment schedulers' nominal allocation)."""
    import numpy as np

    if not isinstance(doc, dict):
        raise InvalidSpec(source, "", "not a saved plan or a RobotFleet with status")
    body = doc.get("status", doc) if "status" in doc else doc
    if not isinstance(body, dict) or "placement" not in body:
        raise InvalidSpec(
            source,
            "placement",
            "missing: not a plan saved by `fogfleet plan --json`, nor a RobotFleet whose status "
            "has a placement",
        )
    entries = body.get("placement") or []
    if not entries and body.get("modulesPlaced"):
        raise InvalidSpec(
            source,
            "status.placement",
            f"lists none of the {body['modulesPlaced']} placed instances (a fleet of more than "
            f"{PLACEMENT_LIST_LIMIT} instances is not listed in its status); save the plan with "
            "`fogfleet plan --json` instead",
        )
    # plain-Deployment schedulers run with nominal requests and no limits
    nominal = body.get("scheduler") in ("k8s-default", "onboard")
    with_limits = bool(body.get("withLimits", not nominal))
    by_instance = {
        (
            e.get("robot") if e.get("robot") not in ("-", None) else "",
            e["module"],
            int(e.get("replica") or 0),
        ): e
        for e in entries
    }
    placement = np.full(problem.n_instances, -1, dtype=np.int64)
    levels = np.zeros(problem.n_instances, dtype=np.int64)
    for i, inst in enumerate(problem.instances):
        entry = by_instance.get((inst.robot, inst.module, inst.replica)) or {}
        node = entry.get("node")
        if node is not None:
            try:
                placement[i] = problem.node_index(node)
            except KeyError as exc:
                raise InvalidSpec(
                    source, "placement", f"node {node!r} is not in the fleet"
                ) from exc
            levels[i] = _rung_of(problem, i, int(placement[i]), entry.get("cpu"))
    if not with_limits:
        return placement, problem.nominal
    return placement, problem.with_levels(levels).limits


def _rung_of(problem: Any, i: int, j: int, cpu: Any) -> int:
    """The ladder rung whose CPU a recorded plan gave instance ``i`` on node ``j`` (0: the
    amount its deadline needs, or no record)."""
    if problem.ladder is None or cpu is None or not problem.allowed[i, j]:
        return 0
    from fogfleet.api.v1alpha1.base import parse_cpu

    rungs = np.flatnonzero(np.isclose(problem.ladder.cpu[i, j], parse_cpu(cpu), atol=1e-6))
    return int(rungs[0]) if len(rungs) and rungs[0] <= problem.ladder.depth[i, j] else 0
