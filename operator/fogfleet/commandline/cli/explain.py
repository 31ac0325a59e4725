"""``fogfleet explain``: why each instance of a module runs where the plan puts it, offline
(the fleet's plan in its folder, planned as one site as ``fogfleet plan`` plans it), with the
same reasons and tables as ``kubectl fogfleet why``."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fogfleet.commandline.kubectl.output import render, why_table
from fogfleet.scheduling.explain.alternatives import explain_module
from fogfleet.snapshot.live import why_doc

from .common import catalog_of, one_fleet, site_plans

__all__ = ["cmd_explain"]


def cmd_explain(args: argparse.Namespace) -> int:
    from fogfleet.snapshot import refused as refusals_of

    catalog = catalog_of(args.paths)
    _, plans = site_plans(catalog, args, args.scheduler, sys.stderr.isatty())
    site = one_fleet(plans, args.paths)

    def refused(i: int) -> dict[int, Any]:  # asked of the build the plan's refusals came from
        return dict(refusals_of(site.snapshot, site.built, i))

    why = explain_module(  # a module (of a robot) the fleet does not run: InvalidSpec, exit 2
        site.problem,
        site.schedule.placement,
        site.schedule.with_limits,
        args.module,
        robot=args.robot,
        objectives=[o.value for o in site.settings.objectives],
        refused=refused,
        held=site.snapshot.held,
        limit=args.limit,
    )
    doc = why_doc(why)
    if site.room:
        print(f"Shared nodes of {site.name}: {site.room}", file=sys.stderr)
    print(render(doc, args.output, why_table(doc) if args.output == "table" else ""))
    return 0
