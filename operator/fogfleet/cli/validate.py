"""``fogfleet validate``: every check ``fogfleet plan`` makes on its input (YAML, the models,
the catalog, each fleet's references and rules), without planning; all errors at once."""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from fogfleet.errors import InvalidSpec

__all__ = ["cmd_validate"]


def cmd_validate(args: argparse.Namespace) -> int:
    from fogfleet.api.loader import load_paths
    from fogfleet.domain.build import build_problem

    errors: list[InvalidSpec] = []
    catalog = load_paths(args.paths, errors)
    for fleet in catalog.fleets:
        try:  # the fleet against the catalog, as `plan` does it before the planner runs
            build_problem(fleet, catalog)
        except InvalidSpec as exc:
            errors.append(exc)
    for error in errors:
        print(f"error: {error}", file=sys.stderr)
    if errors:
        print(f"{len(errors)} error(s) in {', '.join(args.paths)}", file=sys.stderr)
        return 2
    counts = Counter(
        {
            "ComputeNode": len(catalog.nodes),
            "SoftwareModule": len(catalog.modules),
            "RobotFleet": len(catalog.fleets),
        }
    )
    summary = ", ".join(f"{n} {kind}" for kind, n in counts.items())
    other = f"; {len(catalog.ignored)} other object(s) not checked" if catalog.ignored else ""
    print(f"OK: {summary}{other}")
    return 0
