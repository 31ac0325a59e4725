"""``fogfleet plan``: the plans of a folder's fleets, planned as one site, and the placements
saved from them (``fogfleet simulate --placement``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fogfleet.api.v1alpha1.objectives import ObjectiveName
from fogfleet.api.v1alpha1.placement import placement_entries_of
from fogfleet.commandline.exits import BAD_INPUT, OK
from fogfleet.domain.dnnpairs import planned_choice
from fogfleet.domain.miss_rates import format_miss_rate, worst_module
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.explain.shortfall import unplaced_reasons
from fogfleet.scheduling.objectives import module_miss_rates

from .common import catalog_of, degradation, refusal, site_plans, table

__all__ = [
    "cmd_plan",
    "placement_rows",
    "read_placement",
    "recorded_placement",
    "unplaced_modules",
]
MISS_RATE = ObjectiveName.MISS_RATE.value


def placement_rows(problem: Any, schedule: Any) -> list[dict[str, Any]]:
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
        choice = planned_choice(problem, i, j) if j >= 0 else None
        if choice is not None:
            rows[-1]["split"] = {"action": choice.action.name, "reason": choice.reason}
    return rows


def cmd_plan(args: argparse.Namespace) -> int:
    catalog = catalog_of(args.paths)
    out: list[dict[str, Any]] = []
    progress = sys.stderr.isatty() and not args.json
    _, plans = site_plans(catalog, args, args.scheduler, progress)
    for site in plans:
        problem, schedule = site.problem, site.schedule
        rows = placement_rows(problem, schedule)
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
            doc["moduleMissRates"], unplaced=unplaced_modules(problem, schedule.placement)
        )
        if site.room:  # the other fleets of the folder hold room on this one's nodes
            doc["heldByOthers"] = site.room
        if not schedule.feasible:
            doc["infeasible"] = refusal(site)
        if schedule.degraded:
            doc["degradedReason"] = degradation(site)
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
    return OK if all(doc["feasible"] for doc in out) else BAD_INPUT


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
    splits = [r for r in doc["placement"] if "split" in r]
    if splits:
        print("\nSplit networks (RoboEC2's rule over each tail's link):")
        for r in splits:
            print(f"  {r['robot']}/{r['module']}: {r['split']['reason']}")
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
    if "heldByOthers" in doc:
        print(f"Shared nodes: {doc['heldByOthers']}")
    for label, why in doc["unplaced"].items():
        print(f"UNPLACED {label}: {why}", file=sys.stderr)
    if "infeasible" in doc:
        print(f"INFEASIBLE {doc['fleet']}: {doc['infeasible']}", file=sys.stderr)


def unplaced_modules(problem: Any, placement: Any) -> list[str]:
    """The modules with an instance ``placement`` leaves unplaced (-1), sorted."""
    return sorted({problem.instances[int(i)].module for i in np.flatnonzero(placement < 0)})


def read_placement(problem: Any, path: Path) -> tuple[Any, Any]:
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
    if not isinstance(body, dict) or not {"placement", "placementCompact"} & body.keys():
        raise InvalidSpec(
            source,
            "placement",
            "missing: not a plan saved by `fogfleet plan --json`, nor a RobotFleet whose status "
            "has a placement",
        )
    entries = placement_entries_of(body)
    if not entries and body.get("modulesPlaced"):
        raise InvalidSpec(
            source,
            "status.placement",
            f"lists none of the {body['modulesPlaced']} placed instances (nor does "
            "placementCompact); save the plan with `fogfleet plan --json` instead",
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
