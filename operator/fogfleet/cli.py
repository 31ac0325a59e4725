"""The ``fogfleet`` command: plan, simulate and render fleets from CR YAML; generate CRDs; run the
operator; run the benchmarks.

Exit codes: 0 ok, 1 unexpected failure, 2 bad input (the message names object, field, reason)
or an infeasible fleet.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fogfleet.errors import FogfleetError, InvalidSpec

__all__ = ["main"]

SCHEDULERS = ("nsga2", "k8s-default", "onboard", "random", "exact")
AUTOSCALING_FIRST_SEED = 10


def _catalog(paths: Sequence[str]) -> Any:
    from fogfleet.api.loader import load_paths

    catalog = load_paths(paths)
    if not catalog.fleets:
        raise InvalidSpec(
            ", ".join(paths), "", "no RobotFleet found (pass the folder or file with the fleet)"
        )
    return catalog


def _fleets(catalog: Any, name: str | None) -> list[Any]:
    fleets = [f for f in catalog.fleets if name is None or f.metadata.name == name]
    if not fleets:
        raise InvalidSpec(f"RobotFleet/{name}", "", "not found in the given files")
    return fleets


def _settings(fleet: Any, scheduler: str | None, seed: int | None, args: argparse.Namespace) -> Any:
    s = fleet.spec.scheduler
    update: dict[str, Any] = {}
    if scheduler:
        update["algorithm"] = scheduler
    if seed is not None:
        update["seed"] = seed
    for attr in ("population", "generations"):
        if getattr(args, attr, None):
            update[attr] = getattr(args, attr)
    if getattr(args, "time_budget", None):
        update["time_budget_millis"] = int(args.time_budget * 1000)
    return s.model_copy(update=update) if update else s


def _progress(enabled: bool) -> tuple[Callable[[int, int], None] | None, Callable[[], None]]:
    if not enabled:
        return None, lambda: None
    from tqdm import tqdm

    bar: dict[str, Any] = {}

    def update(gen: int, total: int) -> None:
        if "bar" not in bar:
            bar["bar"] = tqdm(total=total, desc="NSGA-II", unit="gen", file=sys.stderr, leave=False)
        b = bar["bar"]
        b.update(gen - b.n)

    def close() -> None:
        if "bar" in bar:
            bar["bar"].close()

    return update, close


def _plan(fleet: Any, catalog: Any, settings: Any, show_progress: bool) -> tuple[Any, Any]:
    from fogfleet.domain.build import build_problem
    from fogfleet.scheduling.solver import plan

    problem = build_problem(fleet, catalog)
    progress, close = _progress(show_progress and settings.algorithm == "nsga2")
    try:
        schedule = plan(problem, settings, progress=progress)
    finally:
        close()
    return problem, schedule


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
    return rows


def _table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]

    def line(r: Sequence[object]) -> str:
        return "  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True))

    return "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])


def cmd_plan(args: argparse.Namespace) -> int:
    catalog = _catalog(args.paths)
    out: list[dict[str, Any]] = []
    infeasible = False
    for fleet in _fleets(catalog, args.fleet):
        settings = _settings(fleet, args.scheduler, args.seed, args)
        problem, schedule = _plan(fleet, catalog, settings, sys.stderr.isatty() and not args.json)
        infeasible |= not schedule.feasible
        rows = _placement_rows(problem, schedule)
        doc = {
            "fleet": f"{problem.namespace}/{problem.fleet}",
            "scheduler": schedule.scheduler,
            "feasible": schedule.feasible,
            "withLimits": schedule.with_limits,
            "placement": rows,
            "objectives": schedule.objectives,
            "durationSeconds": round(schedule.duration_seconds, 4),
            "choiceReason": schedule.choice_reason,
            "unplaced": {problem.label(i): why for i, why in schedule.reasons.items()},
        }
        out.append(doc)
        if args.plot:
            from fogfleet.plot import plot_plan

            plot_plan(problem, schedule, Path(args.plot))
        if not args.json:
            _print_plan(doc)
    if args.json:
        print(json.dumps(out[0] if len(out) == 1 else out, indent=2))
    return 2 if infeasible else 0


def _print_plan(doc: dict[str, Any]) -> None:
    print(
        f"Fleet {doc['fleet']}  scheduler={doc['scheduler']}  feasible={doc['feasible']}  "
        f"({doc['durationSeconds']:.2f} s)"
    )
    rows = [
        [
            r["robot"],
            r["module"] + (f"#{r['replica']}" if r["robot"] == "-" else ""),
            r["node"] or "UNPLACED",
            r["tier"] or "-",
            f"{r['cpu']:g}" if r["cpu"] is not None else "-",
        ]
        for r in doc["placement"]
    ]
    print(_table(rows, ["ROBOT", "MODULE", "NODE", "TIER", "CPU"]))
    print()
    print("Objectives: " + ", ".join(f"{k}={v:.4g}" for k, v in doc["objectives"].items()))
    if doc["choiceReason"]:
        print(f"Choice: {doc['choiceReason']}")
    for label, why in doc["unplaced"].items():
        print(f"UNPLACED {label}: {why}", file=sys.stderr)


def cmd_simulate(args: argparse.Namespace) -> int:
    from fogfleet.domain.build import build_problem
    from fogfleet.scheduling.solver import plan
    from fogfleet.sim import simulate

    catalog = _catalog(args.paths)
    fleet = _fleets(catalog, args.fleet)[0]
    problem = build_problem(fleet, catalog)
    names = (
        list(SCHEDULERS[:3])
        if args.scheduler == "all"
        else [args.scheduler or fleet.spec.scheduler.algorithm]
    )
    placements: dict[str, tuple[Any, bool]] = {}
    if args.placement:
        placements["recorded"] = _read_placement(problem, Path(args.placement))
    for name in names:
        settings = _settings(fleet, str(name), args.seed, args)
        schedule = plan(problem, settings)
        placements[str(name)] = (schedule.placement, schedule.with_limits)
    result: dict[str, Any] = {}
    for name, (placement, with_limits) in placements.items():
        sim = simulate(
            problem,
            placement,
            problem.allocation(with_limits),
            duration_s=args.duration,
            seed=args.seed if args.seed is not None else 0,
            all_active=args.all_active,
        )
        result[name] = {
            "missRate": sim.miss_rate,
            "modules": dict(sim.module_miss_rate),
            "nodeUtilisation": {
                problem.nodes[j].name: u for j, u in enumerate(sim.node_utilisation)
            },
        }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    modules = sorted({m for r in result.values() for m in r["modules"]})
    rows = [
        [m, *(f"{100 * result[s]['modules'].get(m, 0.0):.2f}%" for s in result)] for m in modules
    ]
    rows.append(["OVERALL", *(f"{100 * result[s]['missRate']:.2f}%" for s in result)])
    print(
        f"Missed-cycle rate, fleet {problem.namespace}/{problem.fleet}, "
        f"{args.duration:g} s simulated, seed {args.seed or 0}, "
        + ("all modules active" if args.all_active else "activation rates of the modules")
    )
    print(_table(rows, ["MODULE", *result.keys()]))
    return 0


def _read_placement(problem: Any, path: Path) -> tuple[Any, bool]:
    """A placement saved by ``fogfleet plan --json`` or read back from a fleet's status."""
    import numpy as np
    import yaml

    doc = yaml.safe_load(path.read_text())
    if not isinstance(doc, dict):
        raise InvalidSpec(str(path), "", "not a saved plan or a RobotFleet with status")
    body = doc.get("status", doc) if "status" in doc else doc
    entries = body.get("placement") or []
    # plain-Deployment schedulers run with nominal requests and no limits
    nominal = body.get("scheduler") in ("k8s-default", "onboard")
    with_limits = bool(body.get("withLimits", not nominal))
    index = {
        (
            e.get("robot") if e.get("robot") not in ("-", None) else "",
            e["module"],
            int(e.get("replica") or 0),
        ): e.get("node")
        for e in entries
    }
    placement = np.full(problem.n_instances, -1, dtype=np.int64)
    for i, inst in enumerate(problem.instances):
        node = index.get((inst.robot, inst.module, inst.replica))
        if node is not None:
            try:
                placement[i] = problem.node_index(node)
            except KeyError as exc:
                raise InvalidSpec(
                    str(path), "placement", f"node {node!r} is not in the fleet"
                ) from exc
    return placement, with_limits


def cmd_render(args: argparse.Namespace) -> int:
    import yaml

    from fogfleet.render.deployments import (
        LABEL_FLEET,
        LABEL_MANAGED_BY,
        MANAGER,
        _dns,
        label_value,
        render_fleet,
    )
    from fogfleet.render.ros import (
        RosWiring,
        discovery_servers,
        fleet_network_policy,
        service_address,
    )

    catalog = _catalog(args.paths)
    docs: list[dict[str, Any]] = []
    for fleet in _fleets(catalog, args.fleet):
        settings = _settings(fleet, args.scheduler, args.seed, args)
        problem, schedule = _plan(fleet, catalog, settings, False)
        ns = problem.namespace
        modules = {name: m for (mns, name), m in catalog.modules.items() if mns == ns}
        wiring = None
        if fleet.spec.ros.enabled:
            labels = {LABEL_FLEET: label_value(problem.fleet), LABEL_MANAGED_BY: MANAGER}
            servers = discovery_servers(problem, fleet.spec.ros, labels, [], _dns)
            # offline: the Services' DNS names (the operator uses their cluster IPs)
            wiring = RosWiring(fleet.spec.ros, {r: service_address(s) for r, s, _ in servers})
            for _, service, deployment in servers:
                docs += [service, deployment]
            ports = sorted({p for m in modules.values() for p in m.spec.template.metrics_ports()})
            docs.append(
                fleet_network_policy(
                    name=_dns(f"{problem.fleet}-pods")[:63],
                    namespace=ns,
                    selector={LABEL_FLEET: label_value(problem.fleet)},
                    metrics_ports=ports,
                    owner_refs=[],
                )
            )
        docs.extend(
            render_fleet(
                problem,
                modules,
                schedule.placement,
                baseline=schedule.scheduler == "k8s-default",
                plan_id=f"cli-{schedule.scheduler}-{settings.seed}",
                wiring=wiring,
            )
        )

    class _NoAliases(yaml.SafeDumper):
        def ignore_aliases(self, data: Any) -> bool:
            return True

    print(yaml.dump_all(docs, Dumper=_NoAliases, sort_keys=False), end="")
    return 0


def cmd_crds(args: argparse.Namespace) -> int:
    from fogfleet.api import crdgen

    if args.check:
        drift = crdgen.check_crds(Path(args.check))
        for line in drift:
            print(line, file=sys.stderr)
        if drift:
            print(
                "CRDs drifted from the models: run `make crds` and commit the result.",
                file=sys.stderr,
            )
            return 1
        print(f"{args.check}: CRDs match the models")
        return 0
    for path in crdgen.write_crds(Path(args.out)):
        print(path)
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from fogfleet.operator_main import run
    from fogfleet.settings import Settings

    run(Settings())
    return 0


def cmd_twin(args: argparse.Namespace) -> int:
    from fogfleet.twin.app import run_twin

    return int(run_twin(args) or 0)


def cmd_bench(args: argparse.Namespace) -> int:
    if args.suite == "autoscaling":
        from fogfleet.autoscaling import bench as abench

        # the predictive policy's settings were tuned on seeds 1-5: report held-out seeds
        first = AUTOSCALING_FIRST_SEED
        seeds = [args.seed] if args.seed is not None else list(range(first, first + args.runs))
        results = {s: abench.run_benchmark(s) for s in seeds}
        if args.json:
            print(json.dumps(results[seeds[0]] if len(seeds) == 1 else results, indent=2))
        else:
            print(abench.format_table(results))
        return 0
    from fogfleet import benchmarks

    report = benchmarks.run_scheduling(runs=args.runs, quick=args.quick)
    print(json.dumps(report, indent=2) if args.json else benchmarks.format_scheduling(report))
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fogfleet", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    def fleet_args(sp: argparse.ArgumentParser, scheduler_choices: Sequence[str]) -> None:
        sp.add_argument("paths", nargs="+", help="CR YAML files or folders")
        sp.add_argument("--fleet", help="only this RobotFleet (by name)")
        sp.add_argument(
            "--scheduler", choices=scheduler_choices, help="override spec.scheduler.algorithm"
        )
        sp.add_argument("--seed", type=int, help="override spec.scheduler.seed")
        sp.add_argument("--population", type=int, help="override spec.scheduler.population")
        sp.add_argument("--generations", type=int, help="override spec.scheduler.generations")
        sp.add_argument(
            "--time-budget", type=float, help="seconds; override spec.scheduler.timeBudgetMillis"
        )

    sp = sub.add_parser("plan", help="print the placement table and objectives")
    fleet_args(sp, SCHEDULERS)
    sp.add_argument("--json", action="store_true")
    sp.add_argument("--plot", metavar="FILE.png", help="draw the Pareto front and node utilisation")
    sp.set_defaults(func=cmd_plan)

    sp = sub.add_parser("simulate", help="simulate plans and print missed-cycle rates")
    fleet_args(sp, (*SCHEDULERS, "all"))
    sp.add_argument("--duration", type=float, default=120.0, help="simulated seconds (default 120)")
    sp.add_argument(
        "--all-active",
        action="store_true",
        help="every module active all the time (the paper's IV-B setting) instead of the "
        "activation rates",
    )
    sp.add_argument(
        "--placement",
        help="also simulate a placement saved from `plan --json` or a fleet's YAML with status",
    )
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(func=cmd_simulate)

    sp = sub.add_parser("render", help="print the Deployments the operator would apply")
    fleet_args(sp, SCHEDULERS)
    sp.set_defaults(func=cmd_render)

    sp = sub.add_parser("crds", help="write (or check) the CRD YAML generated from the models")
    g = sp.add_mutually_exclusive_group(required=True)
    g.add_argument("--out", help="folder to write")
    g.add_argument("--check", help="folder to compare; exit 1 on drift")
    sp.set_defaults(func=cmd_crds)

    sp = sub.add_parser("run", help="run the operator (settings from FOGFLEET_* variables)")
    sp.set_defaults(func=cmd_run)

    sp = sub.add_parser(
        "twin", help="serve simulated workload metrics of fogfleet's pods on 127.0.0.1"
    )
    sp.add_argument("--scenario", required=True, help="load scenario YAML (re-read on change)")
    sp.add_argument("--port", type=int, default=9123, help="metrics port on 127.0.0.1")
    sp.add_argument("--namespace", help="only pods of this namespace")
    sp.add_argument("--kubeconfig", help="default: $KUBECONFIG or in-cluster")
    sp.set_defaults(func=cmd_twin)

    sp = sub.add_parser("bench", help="run a benchmark and print a table")
    sp.add_argument("suite", choices=("scheduling", "autoscaling"))
    sp.add_argument("--seed", type=int)
    sp.add_argument("--runs", type=int, default=5, help="seeds / repetitions (default 5)")
    sp.add_argument("--quick", action="store_true", help="smaller instances, for a smoke run")
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(func=cmd_bench)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    started = time.perf_counter()
    try:
        code = int(args.func(args))
    except InvalidSpec as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except FogfleetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # pragma: no cover - `fogfleet render | head`
        return 0
    del started
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
