"""``fogfleet simulate``: the simulated missed cycles of plans side by side, for each fleet the
command selects, planned as ``fogfleet plan`` plans the folder (one site: the fleets before it
hold their room)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from fogfleet.commandline.exits import BAD_INPUT, OK
from fogfleet.domain.miss_rates import format_miss_rate, worst_module
from fogfleet.domain.rows import Learnt
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.objectives import module_miss_rates

from .common import (
    SCHEDULERS,
    catalog_of,
    one_fleet,
    refusal,
    settings_of,
    site_plans,
    solver,
    table,
)
from .planning import read_placement, unplaced_modules

__all__ = ["REFERENCES", "cmd_simulate"]

# The baselines ``simulate --scheduler all`` runs beside the planner: that one of them cannot
# place the fleet (the on-board reference on a site whose robots are too small) is a result
# of the comparison, reported, not an error of the run.
REFERENCES = ("k8s-default", "onboard")


def _model(path: str | None) -> Any:
    """The execution model of ``--model`` (the declared one without it)."""
    from fogfleet.sim import DECLARED, ExecutionModel

    if path is None:
        return DECLARED
    try:
        return ExecutionModel.from_json(json.loads(Path(path).read_text(encoding="utf-8")))
    except OSError as exc:
        raise InvalidSpec(path, "", exc.strerror or "cannot be read") from exc
    except ValueError as exc:  # JSONDecodeError included
        raise InvalidSpec(path, "", str(exc)) from exc


def cmd_simulate(args: argparse.Namespace) -> int:
    if args.model and args.from_prometheus:
        raise InvalidSpec("--model", "", "give --model or --from-prometheus, not both")
    model = _model(args.model)
    catalog = catalog_of(args.paths)
    # --scheduler all compares schedulers on the site as the fleets' own schedulers plan it
    site = None if args.scheduler == "all" else args.scheduler
    _, plans = site_plans(catalog, args, site)
    if args.placement:  # a saved plan is one fleet's
        plans = [one_fleet(plans, args.paths)]
    results: dict[str, dict[str, Any]] = {}
    infeasible: list[str] = []  # the planner's: an error (exit 2)
    references: list[str] = []  # a baseline's beside it (--scheduler all): a result
    for plan in plans:
        result, errors, refs = _simulate_fleet(plan, args, model)
        results[plan.name] = result
        infeasible += [f"{plan.name} {e}" if len(plans) > 1 else e for e in errors]
        references += refs
    for line in [*infeasible, *references]:
        print(f"INFEASIBLE {line}", file=sys.stderr)
    if args.json:
        print(json.dumps(next(iter(results.values())) if len(results) == 1 else results, indent=2))
        return BAD_INPUT if infeasible else OK
    for k, (name, result) in enumerate(results.items()):
        if k:
            print()
        _print_table(name, result, args)
    return BAD_INPUT if infeasible else OK


def _simulate_fleet(
    plan: Any, args: argparse.Namespace, model: Any
) -> tuple[dict[str, Any], list[str], list[str]]:
    """One fleet's plans simulated under ``model`` (``sim.ExecutionModel``): each scheduler's
    (the site's own where it is the one the site ran), a recorded one, and the re-plans from
    measured profiles; and what could not be placed (the planner's: errors; a reference's:
    results)."""
    from fogfleet.snapshot import problem_of

    fleet, problem = plan.snapshot.fleet, plan.built
    learnt: dict[tuple[str, str], tuple[Learnt, float]] = {}
    if args.from_prometheus:
        from .observed import describe, learnt_corrections

        learnt = learnt_corrections(args.from_prometheus, fleet, plan.snapshot.catalog, args.window)
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
        placements["recorded"] = read_placement(problem, Path(args.placement))
    infeasible: list[str] = []
    references: list[str] = []
    solve = solver(False)
    for name in names:
        settings = settings_of(fleet, str(name), args.seed, args)
        schedule = plan.schedule if settings == plan.settings else solve(problem, settings)
        planned = problem.with_levels(schedule.levels)
        placements[str(name)] = (schedule.placement, planned.allocation(schedule.with_limits))
        if not schedule.feasible:
            why = refusal(dataclasses.replace(plan, problem=planned, schedule=schedule))
            if len(names) > 1 and str(name) in REFERENCES:
                references.append(f"{name} (a reference, compared only): {why}")
            else:
                infeasible.append(f"{name}: {why}")
    if factors:  # what re-planning with the measured profiles would give
        from fogfleet.sim.model import under_corrections

        real = problem_of(dataclasses.replace(plan.snapshot, corrections=factors))
        for name in names:
            schedule = solve(real, settings_of(fleet, str(name), args.seed, args))
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
        sim = model.simulate(
            problem,
            placement,
            allocation,
            args.duration,
            args.seed if args.seed is not None else 0,
            all_active=args.all_active,
        )
        unplaced = unplaced_modules(problem, placement)
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
            "placement": _instances(problem, placement, allocation),
        }
    return result, infeasible, references


def _instances(problem: Any, placement: Any, allocation: Any) -> list[dict[str, Any]]:
    """Each instance's node and the CPU it requests there, as ``plan --json`` lists them."""
    rows = []
    for i, inst in enumerate(problem.instances):
        j = int(placement[i])
        rows.append(
            {
                "robot": inst.robot or "-",
                "module": inst.module,
                "replica": inst.replica,
                "node": problem.nodes[j].name if j >= 0 else None,
                "cpu": float(allocation.cpu_request[i, j]) if j >= 0 else None,
            }
        )
    return rows


def _print_table(fleet: str, result: dict[str, Any], args: argparse.Namespace) -> None:
    """One fleet's missed-cycle rates per module, a column per plan."""
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
        f"Missed-cycle rate, fleet {fleet}, "
        f"{args.duration:g} s simulated, seed {args.seed or 0}, "
        + ("all modules active" if args.all_active else "activation rates of the modules")
    )
    print(table(rows, ["MODULE", *result.keys()]))
