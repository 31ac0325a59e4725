"""``fogfleet validate``: every check ``fogfleet plan`` makes on its input (YAML and JSON, the
models, the catalog, each fleet's references and rules), without planning; all errors at once:
every bad field of every object, every bad reference and broken rule of every fleet
(``domain.checks``). Input with no fogfleet object is an error, not "OK: 0 ..." (a wrong
folder, or files kubectl would not read either)."""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from fogfleet.commandline.exits import BAD_INPUT, OK
from fogfleet.errors import InvalidSpec

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
    print(f"OK: {summary}{other}")
    return OK
