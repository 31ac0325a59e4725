"""What the ``fogfleet`` commands share: reading fleets from YAML, selecting them
(``--fleet NAMESPACE/NAME``), scheduler settings from the command line, the site plan every
command plans a folder with (``snapshot.plan_site``), its refusals and degradations naming the
room other fleets hold, the planner with a progress bar, plain-text tables."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any

from fogfleet.errors import InvalidSpec

__all__ = [
    "AUTOSCALING_FIRST_SEED",
    "SCHEDULERS",
    "catalog_of",
    "degradation",
    "fleet_name",
    "one_fleet",
    "refusal",
    "selected",
    "settings_of",
    "site_plans",
    "solver",
    "table",
]

SCHEDULERS = ("nsga2", "k8s-default", "onboard", "random", "exact")
AUTOSCALING_FIRST_SEED = 10


def catalog_of(paths: Sequence[str]) -> Any:
    from fogfleet.api.loader import load_paths

    catalog = load_paths(paths)
    if not catalog.fleets:
        raise InvalidSpec(
            ", ".join(paths), "", "no RobotFleet found (pass the folder or file with the fleet)"
        )
    return catalog


def fleet_name(fleet: Any) -> str:
    """``namespace/name``: how the commands name a fleet, and how ``--fleet`` selects one."""
    return f"{fleet.metadata.namespace or 'default'}/{fleet.metadata.name}"


def selected(catalog: Any, wanted: str | None) -> list[int]:
    """The indices of the fleets ``--fleet`` selects: ``NAMESPACE/NAME`` one fleet, ``NAME``
    every fleet of that name (in any namespace), none given every fleet."""
    fleets = catalog.fleets
    if wanted is None:
        return list(range(len(fleets)))
    namespace, _, name = wanted.rpartition("/")
    picked = [
        k
        for k, f in enumerate(fleets)
        if f.metadata.name == name and (not namespace or fleet_name(f) == wanted)
    ]
    if not picked:
        there = ", ".join(fleet_name(f) for f in fleets)
        raise InvalidSpec(
            f"RobotFleet/{wanted}", "", f"not found in the given files (they hold {there})"
        )
    return picked


def site_plans(
    catalog: Any, args: argparse.Namespace, scheduler: str | None, show_progress: bool = False
) -> tuple[list[Any], list[Any]]:
    """Every fleet of the files planned as one site (``snapshot.plan_site``), up to the last
    one ``--fleet`` selects (the fleets after it cannot change its plan), and the selected
    plans. Every command plans a folder so: each gives an instance the same node and CPU."""
    from fogfleet.snapshot import plan_site

    picked = selected(catalog, args.fleet)
    plans = plan_site(
        catalog,
        catalog.fleets,
        lambda fleet: settings_of(fleet, scheduler, args.seed, args),
        solver(show_progress),
        last=max(picked),
    )
    if len(plans) > 1:  # one site: each fleet plans into what the earlier ones left
        order = ", ".join(p.name for p in plans)
        print(f"Planning {len(plans)} fleets as one site, in this order: {order}", file=sys.stderr)
    return plans, [plans[k] for k in picked]


def one_fleet(plans: list[Any], paths: Sequence[str]) -> Any:
    """The one selected plan of a command that explains one fleet (else: which to pass)."""
    if len(plans) > 1:
        names = ", ".join(p.name for p in plans)
        raise InvalidSpec(
            ", ".join(paths), "--fleet", f"the files hold fleets {names}: pass NAMESPACE/NAME"
        )
    return plans[0]


def refusal(plan: Any) -> str:
    """Why a site plan cannot run as planned, with the room the other fleets hold."""
    from fogfleet.scheduling.explain.shortfall import infeasible_message

    why = infeasible_message(plan.problem, plan.schedule.placement, plan.schedule.reasons)
    return f"{why}; {plan.room}" if plan.room else why


def degradation(plan: Any) -> str:
    """Why a site plan runs below its deadlines' CPU, with the room the other fleets hold."""
    from fogfleet.scheduling.explain.shortfall import degraded_message

    why = degraded_message(plan.problem, plan.schedule.placement)
    return f"{why}; {plan.room}" if plan.room else why


def settings_of(
    fleet: Any, scheduler: str | None, seed: int | None, args: argparse.Namespace
) -> Any:
    s = fleet.spec.scheduler
    update: dict[str, Any] = {}
    if scheduler:
        update["algorithm"] = scheduler
    if seed is not None:
        update["seed"] = seed
    for attr in ("population", "generations"):
        if getattr(args, attr, None) is not None:  # 0 too: the spec's bounds refuse it
            update[attr] = getattr(args, attr)
    if getattr(args, "time_budget", None) is not None:
        update["time_budget_millis"] = int(args.time_budget * 1000)
    if not update:
        return s
    from pydantic import ValidationError

    from fogfleet.api.loader import describe_validation_errors

    try:  # model_copy does not validate: the spec's bounds hold for the options too
        fields = type(s).model_fields
        aliased = {fields[k].alias or k: v for k, v in update.items()}
        return type(s).model_validate({**s.model_dump(by_alias=True), **aliased})
    except ValidationError as exc:
        path, msg = describe_validation_errors(exc)[0]
        flag = {"timeBudgetMillis": "time-budget", "algorithm": "scheduler"}.get(path, path)
        raise InvalidSpec(
            f"RobotFleet/{fleet.metadata.name}",
            f"spec.scheduler.{path}",
            f"{msg} (given by --{flag})",
        ) from exc


def progress_bar(enabled: bool) -> tuple[Callable[[int, int], None] | None, Callable[[], None]]:
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


def solver(show_progress: bool) -> Callable[[Any, Any], Any]:
    """``scheduling.solver.plan``, with a progress bar on stderr for NSGA-II runs."""

    def solve(problem: Any, settings: Any) -> Any:
        from fogfleet.scheduling.solver import plan

        progress, close = progress_bar(show_progress and settings.algorithm == "nsga2")
        try:
            return plan(problem, settings, progress=progress)
        finally:
            close()

    return solve


def table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]

    def line(r: Sequence[object]) -> str:
        return "  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True))

    return "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])
