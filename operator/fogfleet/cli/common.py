"""What the ``fogfleet`` commands share: reading fleets from YAML, scheduler settings from the
command line, the planner with a progress bar, plain-text tables."""

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
    "fleets_of",
    "plan_fleet",
    "settings_of",
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


def fleets_of(catalog: Any, name: str | None) -> list[Any]:
    fleets = [f for f in catalog.fleets if name is None or f.metadata.name == name]
    if not fleets:
        raise InvalidSpec(f"RobotFleet/{name}", "", "not found in the given files")
    return fleets


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


def plan_fleet(fleet: Any, catalog: Any, settings: Any, show_progress: bool) -> tuple[Any, Any]:
    from fogfleet.domain.build import build_problem
    from fogfleet.scheduling.solver import plan

    problem = build_problem(fleet, catalog)
    progress, close = progress_bar(show_progress and settings.algorithm == "nsga2")
    try:
        schedule = plan(problem, settings, progress=progress)
    finally:
        close()
    # a degraded plan's CPU amounts and predictions hold for the degraded problem
    return problem.with_levels(schedule.levels), schedule


def table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]

    def line(r: Sequence[object]) -> str:
        return "  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True))

    return "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])
