"""Emulated links: each real node's link carries its ComputeNode's delay, jitter, rate and loss.

The planner models a path between two nodes as the two uplinks in series (latency adds,
jitter adds in quadrature, loss compounds; operator/fogfleet/domain/network.py). The bed does
the same: every packet crossing a node's link (out of it, or into it) is shaped by that
node's settings, so A -> B sees A's link then B's, and A -> control plane sees A's alone.

This kernel has no ``netem`` qdisc, so where it is missing:

* rate: ``tbf`` on the node's veth (its upload) and on the host-side peer (its download);
* loss: iptables ``statistic --mode random`` DROP in the node's namespace, both directions;
* delay and jitter: iptables NFQUEUE in the node's namespace, both directions, served by a
  userspace delay line (delayline.py) that holds each verdict for delay + N(0, jitter).

Where ``netem`` exists it does delay, jitter and loss itself. iptables rules are only ever
added inside node namespaces; the host only gets ``tc`` on the bed's own host-side veths.

    python e2e/bed/harness.py link bed-robot-1 --delay 20ms --jitter 5ms --loss 100%
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import os
import re
import signal
import subprocess
import sys
from dataclasses import asdict, dataclass, replace
from typing import Any

from e2e.bed import cgroups
from e2e.bed.base import HERE, STATE_DIR, HarnessError, run
from e2e.bed.processes import _alive, _start, _stop

QUEUE = 1
CHAIN = "FF-LINK"


@dataclass(frozen=True)
class LinkSpec:
    """One node's link: one-way delay and jitter (std) in ms, rate in Mbit/s, loss in %."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    rate_mbit: float = 0.0  # 0: unlimited
    loss_percent: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if value < 0:
                raise HarnessError(f"link {name}: must not be negative (got {value})")
        if self.loss_percent > 100:
            raise HarnessError(f"link loss_percent: at most 100 (got {self.loss_percent})")

    @classmethod
    def from_network(cls, entry: dict[str, Any]) -> LinkSpec:
        """From a ComputeNode `network` entry (latencyMillis, jitterMillis, bandwidthMbps, ...)."""
        return cls(
            delay_ms=float(entry.get("latencyMillis", 0)),
            jitter_ms=float(entry.get("jitterMillis", 0)),
            rate_mbit=float(entry.get("bandwidthMbps", 0)),
            loss_percent=float(entry.get("lossPercent", 0)),
        )

    def describe(self) -> str:
        rate = f"{self.rate_mbit:g} Mbit/s" if self.rate_mbit else "unlimited"
        return f"{self.delay_ms:g}±{self.jitter_ms:g} ms, {rate}, loss {self.loss_percent:g}%"


def _in(netns: str, *argv: str) -> list[str]:
    return ["ip", "netns", "exec", netns, *argv]


@functools.cache
def kernel_has_netem() -> bool:
    """Try netem on a scratch namespace's loopback (never on a real interface)."""
    ns = f"ffl-probe-{os.getpid()}"
    if subprocess.run(["ip", "netns", "add", ns], capture_output=True, check=False).returncode:
        return False
    try:
        probe = subprocess.run(
            _in(ns, "tc", "qdisc", "add", "dev", "lo", "root", "netem", "delay", "1ms"),
            capture_output=True,
            check=False,
        )
        return probe.returncode == 0
    finally:
        subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)


def _tbf(prefix: list[str], dev: str, rate_mbit: float) -> None:
    if rate_mbit <= 0:
        subprocess.run([*prefix, "tc", "qdisc", "del", "dev", dev, "root"], capture_output=True,
                       check=False)  # fmt: skip
        return
    burst = max(int(rate_mbit * 1e6 / 8 / 250), 16 * 1024)  # 4 ms worth, at least 16 KiB
    run([*prefix, "tc", "qdisc", "replace", "dev", dev, "root", "tbf",
         "rate", f"{rate_mbit:g}mbit", "burst", str(burst), "latency", "100ms"])  # fmt: skip


def _netem(prefix: list[str], dev: str, spec: LinkSpec) -> None:
    args = ["delay", f"{spec.delay_ms:g}ms"]
    if spec.jitter_ms:
        args += [f"{spec.jitter_ms:g}ms", "distribution", "normal"]
    if spec.loss_percent:
        args += ["loss", f"{spec.loss_percent:g}%"]
    if spec.rate_mbit:
        args += ["rate", f"{spec.rate_mbit:g}mbit"]
    run([*prefix, "tc", "qdisc", "replace", "dev", dev, "root", "netem", *args])


def _iptables(netns: str, *args: str, check: bool = True) -> bool:
    proc = subprocess.run(_in(netns, "iptables", "-t", "mangle", *args), capture_output=True,
                          text=True, check=False)  # fmt: skip
    if check and proc.returncode != 0:
        raise HarnessError(f"iptables {' '.join(args)} in {netns}: {proc.stderr.strip()}")
    return proc.returncode == 0


def _rules(netns: str, dev: str, spec: LinkSpec, delay_line: bool) -> None:
    """The node's FF-LINK chain: loss, then the delay line's queue; hooked both ways on dev."""
    if not _iptables(netns, "-n", "-L", CHAIN, check=False):
        _iptables(netns, "-N", CHAIN)
    _iptables(netns, "-F", CHAIN)
    for hook, flag in (("POSTROUTING", "-o"), ("PREROUTING", "-i")):
        if not _iptables(netns, "-C", hook, flag, dev, "-j", CHAIN, check=False):
            _iptables(netns, "-A", hook, flag, dev, "-j", CHAIN)
    if spec.loss_percent >= 100:
        _iptables(netns, "-A", CHAIN, "-j", "DROP")
    elif spec.loss_percent > 0:
        p = f"{spec.loss_percent / 100:.6f}"
        _iptables(netns, "-A", CHAIN, "-m", "statistic", "--mode", "random",
                  "--probability", p, "-j", "DROP")  # fmt: skip
    if delay_line:
        # --queue-bypass: if the delay line is not running, packets pass undelayed
        _iptables(netns, "-A", CHAIN, "-j", "NFQUEUE", "--queue-num", str(QUEUE),
                  "--queue-bypass")  # fmt: skip


def _delay_line(netns: str, spec: LinkSpec) -> None:
    name = f"link-{netns}"
    settings = STATE_DIR / "links" / f"{netns}.json"
    settings.parent.mkdir(parents=True, exist_ok=True)
    settings.write_text(json.dumps({"delay_ms": spec.delay_ms, "jitter_ms": spec.jitter_ms}))
    pid = _alive(name)
    if pid is not None:
        os.kill(pid, signal.SIGHUP)  # re-read the settings file; held packets keep their time
        return
    pid = _start(name, _in(netns, sys.executable, str(HERE / "delayline.py"), "--queue",
                           str(QUEUE), "--settings", str(settings)))  # fmt: skip
    cgroups.join_links(pid)


def apply_link(netns: str, dev: str, host_dev: str, spec: LinkSpec) -> LinkSpec:
    """Shape the node's link (idempotent; safe while traffic flows)."""
    if kernel_has_netem():
        _netem(_in(netns), dev, spec)
        _netem([], host_dev, spec)
        _rules(netns, dev, replace(spec, loss_percent=0), delay_line=False)
    else:
        _tbf(_in(netns), dev, spec.rate_mbit)
        _tbf([], host_dev, spec.rate_mbit)
        needs_delay = spec.delay_ms > 0 or spec.jitter_ms > 0
        if needs_delay:
            _delay_line(netns, spec)
        _rules(netns, dev, spec, delay_line=needs_delay)
    _write_current(netns, spec)
    return spec


def stop_link(netns: str) -> None:
    """Stop the node's delay line (its rules and qdiscs go with the namespace and the veth)."""
    _stop(f"link-{netns}")


def _write_current(netns: str, spec: LinkSpec) -> None:
    path = STATE_DIR / "links" / f"{netns}.current.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(asdict(spec)) + "\n")


def current(netns: str) -> LinkSpec | None:
    with contextlib.suppress(OSError, ValueError, TypeError):
        return LinkSpec(**json.loads((STATE_DIR / "links" / f"{netns}.current.json").read_text()))
    return None


# --------------------------------------------------------------------------------------------
# command line: harness.py link NODE [--delay 20ms] [--jitter 5ms] [--rate 50mbit] [--loss 100%]


def _number(text: str, units: dict[str, float]) -> float:
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([a-zA-Z%/]*)\s*", text)
    if not m or m.group(2).lower() not in units:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number with one of {list(units)}")
    return float(m.group(1)) * units[m.group(2).lower()]


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="harness.py link", description="Change a real node's link.")
    p.add_argument("node")
    ms = {"": 1.0, "ms": 1.0, "s": 1000.0, "us": 0.001}
    p.add_argument("--delay", type=lambda t: _number(t, ms), help="one-way delay, e.g. 20ms")
    p.add_argument("--jitter", type=lambda t: _number(t, ms), help="jitter (std), e.g. 5ms")
    rates = {"": 1.0, "mbit": 1.0, "kbit": 0.001, "gbit": 1000.0}
    p.add_argument("--rate", type=lambda t: _number(t, rates), help="e.g. 50mbit (0: unlimited)")
    p.add_argument("--loss", type=lambda t: _number(t, {"": 1.0, "%": 1.0}), help="e.g. 100%%")
    p.add_argument("--reset", action="store_true", help="back to the link nodes.yaml declares")
    return p.parse_args(argv)


def change_from_args(ns: argparse.Namespace) -> dict[str, float]:
    pairs = {"delay_ms": ns.delay, "jitter_ms": ns.jitter, "rate_mbit": ns.rate,
             "loss_percent": ns.loss}  # fmt: skip
    return {k: v for k, v in pairs.items() if v is not None}
