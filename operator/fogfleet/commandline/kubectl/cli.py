"""``kubectl fogfleet``: argument parsing and the commands, kubectl's way (``--kubeconfig``,
``--context``, ``-n/--namespace`` defaulting to the context's, ``-o table|json|yaml``).

Exit codes (``fogfleet.commandline.exits``, the same as ``fogfleet``'s): 0 ok, 1 the cluster could
not be read, 2 bad arguments or input (argparse's own code for bad arguments)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from fogfleet.api.kinds import MAX_EXPLAINED, ExplanationFailure, ExplanationPhase
from fogfleet.commandline.exits import OK, positive, run_command
from fogfleet.errors import DependencyUnavailable, InvalidSpec

from .output import FORMATS, diff_table, render, top_table, why_table

if TYPE_CHECKING:  # the planner's code is imported where a command computes (see _run)
    from .live import Source, WhatIf

__all__ = ["main", "parser"]

Connect = Callable[[str | None, str | None], tuple["Source", str]]
Doc = dict[str, Any]
ASK_SECONDS = 5.0  # how long `why` waits for the operator's answer by default


def parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--kubeconfig", help="path to the kubeconfig file (default: $KUBECONFIG)")
    common.add_argument("--context", help="the kubeconfig context to use")
    common.add_argument("-n", "--namespace", help="the fleet's namespace (default: the context's)")
    common.add_argument("-o", "--output", choices=FORMATS, default="table", help="output format")
    p = argparse.ArgumentParser(
        prog="kubectl fogfleet", description=(__doc__ or "").split("\n\n")[0]
    )
    sub = p.add_subparsers(dest="command", required=True)
    sp = sub.add_parser(
        "why", parents=[common], help="where each instance of a module runs and why not elsewhere"
    )
    sp.add_argument("fleet", help="the RobotFleet")
    sp.add_argument("module", help="the SoftwareModule")
    sp.add_argument("--robot", help="only this robot's instance")
    sp.add_argument(
        "--limit",
        type=positive(int),
        default=50,
        help=f"instances explained at most (50; the operator answers up to {MAX_EXPLAINED})",
    )
    sp.add_argument(
        "--local",
        action="store_true",
        help="explain from the API's objects here, without asking the operator",
    )
    sp.add_argument(
        "--wait",
        type=positive(float),
        default=ASK_SECONDS,
        metavar="SECONDS",
        help=f"how long to wait for the operator's answer ({ASK_SECONDS:g})",
    )
    sp = sub.add_parser(
        "top", parents=[common], help="measured vs predicted misses, CPU and split per module"
    )
    sp.add_argument("fleet", help="the RobotFleet")
    sp = sub.add_parser(
        "diff", parents=[common], help="what a re-plan now would move, and each objective's change"
    )
    sp.add_argument("fleet", help="the RobotFleet")
    sp = sub.add_parser("plan", parents=[common], help="plan the live fleet changed; apply nothing")
    sp.add_argument("fleet", help="the RobotFleet")
    sp.add_argument("--what-if", action="store_true", required=True, help="required: plans only")
    sp.add_argument(
        "--without-node",
        action="append",
        default=[],
        metavar="NODE",
        help="a ComputeNode removed (repeatable)",
    )
    sp.add_argument("--add-robot", metavar="NAME", help="a robot added (needs --like)")
    sp.add_argument("--like", metavar="ROBOT", help="the robot --add-robot copies")
    sp.add_argument(
        "--link",
        action="append",
        default=[],
        metavar="ROBOT=MILLIS",
        help="a robot's uplink latency in milliseconds (repeatable)",
    )
    return p


def _what_if(args: argparse.Namespace, p: argparse.ArgumentParser) -> WhatIf:
    if bool(args.add_robot) != bool(args.like):
        p.error("--add-robot and --like go together")
    links: dict[str, float] = {}
    for item in args.link:
        robot, _, millis = item.partition("=")
        try:
            links[robot] = float(millis) / 1000.0
        except ValueError:
            p.error(f"--link {item}: expected ROBOT=MILLIS")
        if not robot or links[robot] <= 0:
            p.error(f"--link {item}: expected ROBOT=MILLIS with MILLIS > 0")
    if not (args.without_node or args.add_robot or links):
        p.error("plan --what-if needs --without-node, --add-robot or --link")
    from .live import WhatIf

    return WhatIf(tuple(args.without_node), args.add_robot, args.like, links)


def _connect(kubeconfig: str | None, context: str | None) -> tuple[Source, str]:
    from .cluster import connect

    return connect(kubeconfig, context)


def main(
    argv: Sequence[str] | None = None,
    connect: Connect = _connect,
    clock: Callable[[], float] = time.time,
) -> int:
    """``kubectl fogfleet``; ``connect`` reaches the cluster, ``clock`` says when "now" is (the
    age of a standby's last takeover in ``top``)."""
    p = parser()
    args = p.parse_args(argv)
    what_if = _what_if(args, p) if args.command == "plan" else None
    return run_command(lambda: _run(args, what_if, connect, clock))


def _run(
    args: argparse.Namespace,
    what_if: WhatIf | None,
    connect: Connect,
    clock: Callable[[], float],
) -> int:
    """Read the fleet, compute the command's document and print it."""
    source, namespace = connect(args.kubeconfig, args.context)
    ns = args.namespace or namespace
    if args.command == "why":
        doc, room = _why(source, ns, args)
        text = render(doc, args.output, why_table(doc) if args.output == "table" else "")
        if room:  # as `fogfleet explain` says it: the fleet was planned into what others left
            print(f"Shared nodes of {doc['fleet']}: {room}", file=sys.stderr)
        print(text)
        return OK
    from .commands import diff_doc, plan_doc, top_doc
    from .live import read_fleet

    live = read_fleet(source, ns, args.fleet)
    if args.command == "top":
        doc = top_doc(live, clock())
        text = render(doc, args.output, top_table(doc) if args.output == "table" else "")
    else:
        changed = read_fleet(source, ns, args.fleet, what_if) if what_if else live
        doc = plan_doc(changed, live) if what_if else diff_doc(live)
        text = render(doc, args.output, diff_table(doc) if args.output == "table" else "")
    print(text)
    return OK


def _why(source: Source, ns: str, args: argparse.Namespace) -> tuple[Doc, str]:
    """The explanation and who else holds room on the fleet's nodes: the operator's answer
    (``ExplanationRequest``, from the plan it holds), else computed here from the API's
    objects, as the operator would (``--local``, or when it cannot answer: no such CRD, no
    right to create requests, no plan of the fleet held, no answer within ``--wait``)."""
    if not args.local and args.limit <= MAX_EXPLAINED:
        spec = {"fleet": args.fleet, "module": args.module, "robot": args.robot}
        try:
            asked = source.ask_explanation(ns, {**spec, "limit": args.limit}, args.wait)
        except DependencyUnavailable as exc:
            asked, why = None, str(exc)
        else:
            why = f"no answer within {args.wait:g} s"
        status = (asked or {}).get("status") or {}
        if status.get("phase") == ExplanationPhase.ANSWERED.value:
            return dict(status.get("explanation") or {}), str(status.get("sharedNodes") or "")
        if status.get("phase") == ExplanationPhase.FAILED.value:
            why = str(status.get("message") or "")
            if status.get("reason") == ExplanationFailure.INVALID_REQUEST.value:
                raise InvalidSpec(f"RobotFleet/{args.fleet}", "", why)
        print(f"The operator did not explain: {why}; explaining here.", file=sys.stderr)
    from fogfleet.snapshot import room_note
    from fogfleet.snapshot.live import why_doc, why_of

    from .live import read_fleet

    live = read_fleet(source, ns, args.fleet)
    doc = why_doc(why_of(live, args.module, args.robot, args.limit))
    return doc, room_note(live.problem, live.snapshot.held)
