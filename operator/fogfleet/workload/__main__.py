"""``python -m fogfleet.workload module | dnn | probe | discovery-server | relay`` (the ROS 2
workload image's entry points)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from fogfleet.contract.dnn import PROFILE_WARMUP
from fogfleet.contract.env import (
    ENV_LOG_INTERVAL,
    ENV_METRICS_HOST,
    ENV_METRICS_PORT,
    ENV_MODULE_SPEC,
    ENV_ROLE,
    METRICS_PORT,
)
from fogfleet.contract.relay import (
    ENV_RELAY_ROUTER,
    ENV_RELAY_ROUTES,
    RELAY_METRICS_PORT,
    routes_from_json,
)

from .dnn.whole import Whole
from .fallback import Role
from .heartbeat import log_interval
from .profile import DEFAULT_OUTPUT, ENV_PROFILE_OUTPUT, profile_cycles, run_profile
from .spec import WorkloadSpec
from .work import describe, work_for

WHOLE_HELP = (
    "experiments (a split module's head): run the network whole, as a module that cannot be "
    "split: on the edge (every frame's input crosses, no local model) or on the robot; the "
    "baselines of make bench-split"
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fogfleet-workload", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("module", help="play the SoftwareModule in $FOGFLEET_MODULE_SPEC")
    m.add_argument("--host", default=os.environ.get(ENV_METRICS_HOST, "0.0.0.0"))
    m.add_argument("--port", type=int, default=int(os.environ.get(ENV_METRICS_PORT, METRICS_PORT)))
    m.add_argument(
        "--work-factor",
        type=_work_factor,
        default=(1.0, ""),
        metavar="F[@HARDWARE_TYPE]",
        help="experiments: do F times the work the profile row says, on every node or only "
        "on that hardware type (a declared profile that is wrong, for the operator to learn)",
    )
    m.add_argument(
        "--cpu-work",
        type=_cpu_work,
        default=None,
        metavar="MILLIS",
        help="milliseconds of CPU per cycle, single-threaded: the module's true work, burnt as "
        "fast as its CPU limit lets it (the kernel's CFS quota decides how long it takes); "
        "without it the workload plays its profile row",
    )
    m.add_argument("--whole", type=Whole, choices=list(Whole), default=None, help=WHOLE_HELP)
    m.add_argument(
        "--log-interval",
        type=_log_seconds,
        default=None,
        metavar="SECONDS",
        help="seconds between the log lines of cycles, misses and messages (default: "
        "$FOGFLEET_LOG_INTERVAL_SECONDS, else 10; 0: none)",
    )
    n = sub.add_parser(
        "dnn",
        help="a split DNN module's head or tail ($FOGFLEET_ROLE) from $FOGFLEET_MODULE_SPEC",
    )
    n.add_argument("--host", default=os.environ.get(ENV_METRICS_HOST, "0.0.0.0"))
    n.add_argument("--port", type=int, default=int(os.environ.get(ENV_METRICS_PORT, METRICS_PORT)))
    n.add_argument("--log-interval", type=_log_seconds, default=None, metavar="SECONDS")
    n.add_argument("--whole", type=Whole, choices=list(Whole), default=None, help=WHOLE_HELP)
    n.add_argument(
        "--link-mbit",
        type=_link_mbit,
        default=None,
        metavar="MBIT",
        help="experiments (the head): hold each tensor back as an uplink of MBIT Mbit/s would "
        "(a slow link on one host)",
    )
    p = sub.add_parser(
        "probe", help="measure the cycle times of the module in $FOGFLEET_MODULE_SPEC (sidecar)"
    )
    p.add_argument("--host", default=os.environ.get(ENV_METRICS_HOST, "0.0.0.0"))
    p.add_argument("--port", type=int, default=9101)
    d = sub.add_parser("discovery-server", help="the robot's Fast DDS discovery server")
    d.add_argument("--listen", default="0.0.0.0")
    d.add_argument("--port", type=int, default=11811)
    d.add_argument("--tcp-port", type=int, default=None, help="also listen on TCP (probes)")
    r = sub.add_parser(
        "relay",
        help=f"carry the routes in ${ENV_RELAY_ROUTES} between this ROS 2 graph and the Zenoh "
        f"router in ${ENV_RELAY_ROUTER} (a cut edge of the plan across the WAN)",
    )
    r.add_argument("--log-interval", type=_log_seconds, default=None, metavar="SECONDS")
    r.add_argument("--host", default=os.environ.get(ENV_METRICS_HOST, "0.0.0.0"))
    r.add_argument(
        "--port", type=int, default=int(os.environ.get(ENV_METRICS_PORT, RELAY_METRICS_PORT))
    )
    ns = parser.parse_args(argv)
    if ns.cmd == "discovery-server":
        from .discovery import run_discovery_server

        run_discovery_server(ns.listen, ns.port, ns.tcp_port)
        return 0
    if ns.cmd == "relay":
        return _relay(ns.log_interval, (ns.host, ns.port))
    try:
        spec = WorkloadSpec.from_env(os.environ)
    except ValueError as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 2
    if spec.dnn_profile is not None and ns.cmd in ("module", "dnn"):
        # a split module's profiling Job: it times the image's models, nothing else
        try:
            dnn_cycles = profile_cycles(os.environ)
        except ValueError as exc:
            print(f"fogfleet-workload: {exc}", file=sys.stderr)
            return 2
        if dnn_cycles is not None:
            return _profile_dnn(spec, spec.dnn_profile, dnn_cycles)
    if ns.cmd == "dnn" or (ns.cmd == "module" and spec.dnn is not None):
        # a split module's pods run the image's default command (module): its spec says it
        return _dnn(spec, ns.host, ns.port, ns.log_interval, getattr(ns, "link_mbit", None),
                    ns.whole)  # fmt: skip
    if getattr(ns, "whole", None) is not None:
        print(f"fogfleet-workload: --whole: only a split module (spec.dnn) runs whole; "
              f"{spec.module}'s spec has no dnn", file=sys.stderr)  # fmt: skip
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
    factor, where = ns.work_factor
    if not where or where == spec.hardware_type:
        spec = dataclasses.replace(spec, work_factor=factor)
    if ns.cpu_work is not None:
        spec = dataclasses.replace(spec, cpu_work_s=ns.cpu_work / 1e3)
    try:
        cycles = profile_cycles(os.environ)
        if cycles is not None and spec.cpu_work_s is None and not spec.profile:
            raise ValueError(
                "no work to profile: give the module its work (--cpu-work MILLIS) or a "
                "profile row for this node"
            )
        what = describe(spec)  # a module with neither its own work nor a row: said here
        every = ns.log_interval if ns.log_interval is not None else log_interval(os.environ)
    except ValueError as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 2
    if cycles is not None:
        return _profile(spec, cycles, what)
    from .module import run_module

    limit = "no CPU limit" if spec.cpu is None else f"{spec.cpu:g} CPU"
    print(
        f"fogfleet-workload: {spec.robot or 'shared'}/{spec.module} on {spec.node} "
        f"({spec.tier or 'any tier'}, {limit}): cycle {spec.cycle_s * 1e3:g} ms, "
        f"activation {spec.activation:.0%}, {what}; "
        + (f"a line every {every:g} s" if every > 0 else "no periodic log lines"),
        flush=True,
    )
    run_module(spec, ns.host, ns.port, log_interval=every)
    return 0


def _dnn(
    spec: WorkloadSpec,
    host: str,
    port: int,
    every: float | None,
    link_mbit: float | None,
    whole: Whole | None = None,
) -> int:
    """A split DNN module's side: its spec must carry ``dnn`` and its role be head or tail."""
    if spec.dnn is None:
        print(f'fogfleet-workload: dnn: {ENV_MODULE_SPEC} has no "dnn" key', file=sys.stderr)
        return 2
    if spec.role not in (Role.HEAD, Role.TAIL):
        print(f"fogfleet-workload: dnn: {ENV_ROLE}={spec.role.value!r}: head or tail",
              file=sys.stderr)  # fmt: skip
        return 2
    if spec.role is Role.HEAD and not spec.publishes:
        print("fogfleet-workload: dnn: the head publishes its answers on the module's first "
              "output topic, and it has none", file=sys.stderr)  # fmt: skip
        return 2
    try:
        seconds = every if every is not None else log_interval(os.environ)
    except ValueError as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 2
    from .dnn.ros import models_folder, run_dnn

    folder = models_folder(os.environ)
    run_dnn(spec, spec.role.value, folder, host, port, seconds, None, link_mbit, whole)
    return 0


def _relay(every: float | None, metrics: tuple[str, int]) -> int:
    """The relay's run (``workload.relay``), from its environment."""
    try:
        routes = routes_from_json(os.environ.get(ENV_RELAY_ROUTES, ""))
        router = os.environ.get(ENV_RELAY_ROUTER, "")
        if not router.startswith(("tcp/", "tls/", "quic/", "udp/")):
            raise ValueError(f"{ENV_RELAY_ROUTER}: a Zenoh endpoint, tcp/HOST:PORT, not {router!r}")
        seconds = every if every is not None else log_interval(os.environ)
    except ValueError as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 2
    from .relay import run_relay

    run_relay(routes, router, log_interval=seconds, metrics=metrics)
    return 0


def _profile(spec: WorkloadSpec, cycles: int, what: str) -> int:
    """A profiling Job's run (``workload.profile``): no ROS, one result line."""
    import random

    work = work_for(spec, random.Random())
    output = os.environ.get(ENV_PROFILE_OUTPUT) or DEFAULT_OUTPUT
    print(
        f"fogfleet-workload: profiling {spec.module} on {spec.node or 'this node'} "
        f"({spec.hardware_type or 'unknown hardware'}, {spec.cpu_label or 'no limit'}): "
        f"{cycles} cycles of {what}",
        flush=True,
    )
    try:
        run_profile(spec, work, cycles, output)
    except OSError as exc:
        print(f"fogfleet-workload: cannot write the profile to {output}: {exc}", file=sys.stderr)
        return 1
    finally:
        work.close()
    return 0


def _profile_dnn(spec: WorkloadSpec, splits: tuple[str, ...], cycles: int) -> int:
    """A split module's profiling Job (``dnn.measure``): no ROS, one result line; a missing
    model, a line too long for a termination message or an unwritable output exits 1, saying
    why (the operator reports the pod's words)."""
    from .dnn.measure import run_dnn_profile
    from .dnn.sessions import models_folder

    folder = models_folder(os.environ)
    output = os.environ.get(ENV_PROFILE_OUTPUT) or DEFAULT_OUTPUT
    print(
        f"fogfleet-workload: profiling {spec.module}'s network on {spec.node or 'this node'} "
        f"({spec.hardware_type or 'unknown hardware'}, {spec.cpu_label or 'no limit'}): "
        f"the whole network, the local model and {len(splits)} split points' heads and tails "
        f"from {folder}, {cycles} frames each after {PROFILE_WARMUP} untimed",
        flush=True,
    )
    try:
        run_dnn_profile(folder, splits, cycles, output)
    except (OSError, ValueError) as exc:
        print(f"fogfleet-workload: {exc}", file=sys.stderr)
        return 1
    return 0


def _bounded(text: str, most: float, what: str, given: str = "") -> float:
    """A number above 0 and at most ``most``, or argparse's error naming ``what`` (and the
    argument as ``given``, when ``text`` is only part of it)."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 < value <= most:
        raise argparse.ArgumentTypeError(
            f"{given or text!r}: {what} a number above 0, at most {most:g}"
        )
    return value


def _cpu_work(text: str) -> float:
    """``MILLIS``: above 0, at most 10000."""
    return _bounded(text, 10000, "milliseconds of CPU per cycle,")


def _link_mbit(text: str) -> float:
    """``MBIT``: above 0, at most 100000."""
    return _bounded(text, 100000, "Mbit/s,")


def _log_seconds(text: str) -> float:
    """``SECONDS``: 0 or more."""
    try:
        return log_interval({ENV_LOG_INTERVAL: text})
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: seconds, 0 or more") from exc


def _work_factor(text: str) -> tuple[float, str]:
    """``F`` or ``F@HARDWARE_TYPE``."""
    number, _, where = text.partition("@")
    return _bounded(number, 100, "F or F@HARDWARE_TYPE, F", given=text), where


if __name__ == "__main__":
    sys.exit(main())
