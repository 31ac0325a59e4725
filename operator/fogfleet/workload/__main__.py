"""``python -m fogfleet.workload module | probe | discovery-server`` (the ROS 2 workload image's
entry points)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from .spec import WorkloadSpec


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fogfleet-workload", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("module", help="play the SoftwareModule in $FOGFLEET_MODULE_SPEC")
    m.add_argument("--host", default=os.environ.get("FOGFLEET_METRICS_HOST", "0.0.0.0"))
    m.add_argument("--port", type=int, default=int(os.environ.get("FOGFLEET_METRICS_PORT", "9100")))
    m.add_argument(
        "--work-factor",
        type=_work_factor,
        default=(1.0, ""),
        metavar="F[@HARDWARE_TYPE]",
        help="experiments: do F times the work the profile row says, on every node or only "
        "on that hardware type (a declared profile that is wrong, for the operator to learn)",
    )
    p = sub.add_parser(
        "probe", help="measure the cycle times of the module in $FOGFLEET_MODULE_SPEC (sidecar)"
    )
    p.add_argument("--host", default=os.environ.get("FOGFLEET_METRICS_HOST", "0.0.0.0"))
    p.add_argument("--port", type=int, default=9101)
    d = sub.add_parser("discovery-server", help="the robot's Fast DDS discovery server")
    d.add_argument("--listen", default="0.0.0.0")
    d.add_argument("--port", type=int, default=11811)
    d.add_argument("--tcp-port", type=int, default=None, help="also listen on TCP (probes)")
    ns = parser.parse_args(argv)
    if ns.cmd == "discovery-server":
        from .discovery import run_discovery_server

        run_discovery_server(ns.listen, ns.port, ns.tcp_port)
        return 0
    try:
        spec = WorkloadSpec.from_env(os.environ)
    except ValueError as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 2
    if ns.cmd == "probe":
        from .probe import run_probe

        print(
            f"fogfleet-workload: probing {spec.robot or 'shared'}/{spec.module}: outputs "
            f"{', '.join(t.name for t in spec.publishes) or 'none'}, cycle "
            f"{spec.cycle_s * 1e3:g} ms",
            flush=True,
        )
        run_probe(spec, ns.host, ns.port)
        return 0
    from .module import run_module

    factor, where = ns.work_factor
    if not where or where == spec.hardware_type:
        spec = dataclasses.replace(spec, work_factor=factor)
    limit = "no CPU limit" if spec.cpu is None else f"{spec.cpu:g} CPU"
    print(
        f"fogfleet-workload: {spec.robot or 'shared'}/{spec.module} on {spec.node} "
        f"({spec.tier or 'any tier'}, {limit}): cycle {spec.cycle_s * 1e3:g} ms, "
        f"activation {spec.activation:.0%}, work {spec.row.mean_s * 1e3:g}±"
        f"{spec.row.std_s * 1e3:g} ms at {spec.row.cpu:g} CPU"
        + (f" x{spec.work_factor:g}" if spec.work_factor != 1 else ""),
        flush=True,
    )
    run_module(spec, ns.host, ns.port)
    return 0


def _work_factor(text: str) -> tuple[float, str]:
    """``F`` or ``F@HARDWARE_TYPE``."""
    number, _, where = text.partition("@")
    try:
        value = float(number)
    except ValueError:
        value = -1.0
    if not 0 < value <= 100:
        raise argparse.ArgumentTypeError(
            f"{text!r}: F or F@HARDWARE_TYPE, F a number above 0, at most 100"
        )
    return value, where


if __name__ == "__main__":
    sys.exit(main())
