"""``fogfleet explain``: why each instance of a module runs where the plan puts it, offline
(the plan of the fleet's YAML), with the same reasons and tables as ``kubectl fogfleet why``."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fogfleet.domain.build import build_problem, refusals
from fogfleet.errors import InvalidSpec
from fogfleet.plugin.commands import why_doc
from fogfleet.plugin.output import render, why_table
from fogfleet.scheduling.why import explain_module

from .common import catalog_of, fleets_of, plan_fleet, settings_of

__all__ = ["cmd_explain"]


def cmd_explain(args: argparse.Namespace) -> int:
    catalog = catalog_of(args.paths)
    fleets = fleets_of(catalog, args.fleet)
    if len(fleets) > 1:
        names = ", ".join(f.metadata.name for f in fleets)
        raise InvalidSpec(
            ", ".join(args.paths), "--fleet", f"the files hold fleets {names}: pass one"
        )
    fleet = fleets[0]
    settings = settings_of(fleet, args.scheduler, args.seed, args)
    problem, schedule = plan_fleet(fleet, catalog, settings, sys.stderr.isatty())
    plain = build_problem(fleet, catalog)  # the build the plan's refusals came from

    def refused(i: int) -> dict[int, Any]:
        return dict(refusals(fleet, catalog, plain.instances[i]))

    why = explain_module(  # a module (of a robot) the fleet does not run: InvalidSpec, exit 2
        problem,
        schedule.placement,
        schedule.with_limits,
        args.module,
        robot=args.robot,
        objectives=[o.value for o in settings.objectives],
        refused=refused,
        limit=args.limit,
    )
    doc = why_doc(why)
    print(render(doc, args.output, why_table(doc) if args.output == "table" else ""))
    return 0
