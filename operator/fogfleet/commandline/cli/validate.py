"""``fogfleet validate``: would ``fogfleet plan`` accept this input? Every check ``plan`` makes
on it (YAML and JSON, the models, the catalog, each fleet's references and rules), all errors
at once: every bad field of every object, every bad reference and broken rule of every fleet
(``domain.checks``). Then, when those pass, the folder's fleets are planned as one site as
``plan`` plans them (``snapshot.plan_site``, each fleet with its own ``spec.scheduler``): a
fleet no placement fits is an error with ``plan``'s refusal, naming the room other fleets
hold; a degraded one is a warning. ``--no-plan`` stops after the checks (fast: no planner
runs). Input with no fogfleet object is an error, not "OK: 0 ..." (a wrong folder, or files
kubectl would not read either)."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from typing import Any

from fogfleet.commandline.exits import BAD_INPUT, OK
from fogfleet.errors import InvalidSpec

from .common import degradation, refusal, site_plans

__all__ = ["cmd_validate"]


def cmd_validate(args: argparse.Namespace) -> int:
    from fogfleet.api.loader import load_paths
    from fogfleet.domain.checks import fleet_errors
    from fogfleet.snapshot import built_problem, snapshot_of_catalog

    errors: list[InvalidSpec] = []
    catalog = load_paths(args.paths, errors)
    for fleet in catalog.fleets:
        found = fleet_errors(fleet, catalog)
        if not found:
            try:  # the fleet against the catalog, as `plan` does it before the planner runs
                built_problem(snapshot_of_catalog(catalog, fleet))
            except InvalidSpec as exc:
                found = [exc]
        shown = {str(e) for e in errors}  # a node two fleets use is wrong once
        errors += [e for e in found if str(e) not in shown]
    if not (catalog.nodes or catalog.modules or catalog.fleets or errors):
        other = f" ({len(catalog.ignored)} other object(s) skipped)" if catalog.ignored else ""
        errors.append(  # kubectl apply too refuses a folder with nothing to apply
            InvalidSpec(
                ", ".join(args.paths),
                "",
                f"no ComputeNode, SoftwareModule or RobotFleet found{other}",
            )
        )
    for skipped in catalog.ignored:  # read, not checked: a misspelt group lands here
        print(f"skipped: {skipped} in {skipped.source}: {skipped.why}", file=sys.stderr)
    planned = "; not planned (--no-plan)" if args.no_plan and catalog.fleets else ""
    if not errors and catalog.fleets and not args.no_plan:
        errors, planned = _plan_site(catalog, args)
    for error in errors:
        print(f"error: {error}", file=sys.stderr)
    if errors:
        print(f"{len(errors)} error(s) in {', '.join(args.paths)}", file=sys.stderr)
        return BAD_INPUT
    counts = Counter(
        {
            "ComputeNode": len(catalog.nodes),
            "SoftwareModule": len(catalog.modules),
            "RobotFleet": len(catalog.fleets),
        }
    )
    summary = ", ".join(f"{n} {kind}" for kind, n in counts.items())
    other = f"; {len(catalog.ignored)} other object(s) skipped" if catalog.ignored else ""
    print(f"OK: {summary}{other}{planned}")
    return OK


def _plan_site(catalog: Any, args: argparse.Namespace) -> tuple[list[InvalidSpec], str]:
    """The folder's fleets planned as one site, as ``plan`` plans them (``site_plans``, each
    fleet with its own ``spec.scheduler``): the refusals (as errors) and what the OK line
    says of it; a degraded fleet is warned about on stderr."""
    _, plans = site_plans(catalog, args, None)
    errors: list[InvalidSpec] = []
    for plan in plans:
        if not plan.schedule.feasible:
            errors.append(InvalidSpec(f"RobotFleet/{plan.name}", "spec", refusal(plan)))
        elif plan.schedule.degraded:
            print(f"warning: DEGRADED {plan.name}: {degradation(plan)}", file=sys.stderr)
    fits = (
        f"planned as one site: all {len(plans)} fleets fit"
        if len(plans) > 1
        else "planned: it fits"
    )
    return errors, f"; {fits}"
