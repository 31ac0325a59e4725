"""Faults of a real node's own processes (issue 37, items 2 and 6), injected by pid.

    restart(node, "kubelet")      SIGTERM the node's kubelet (or containerd, kube-proxy); its
                                  nodehost starts it again (nodehost.py) - as systemd would
    reboot(node)                  SIGKILL every process in the node's cgroups (containers,
                                  shims, containerd, kubelet, kube-proxy and the nodehost
                                  itself: a power cut), then boot the node again

    python e2e/bed/harness.py fault NODE restart kubelet|containerd|kube-proxy
    python e2e/bed/harness.py fault NODE reboot [--down SECONDS]

The pids come from the table the nodehost keeps (``NODE_DIR/pids.json``), each checked against
its start time before a signal is sent, so nothing but that one process is ever signalled.

What a reboot loses and keeps is what a real machine loses and keeps. The node's mount
namespace dies with its last process, and with it its tmpfs ``/run/containerd`` (the shims'
sockets, the running tasks' state, the pods' network namespaces): the boot starts from an empty
``/run``. What is on the node's "disk" stays: ``/var/lib/kubelet`` (pod dirs, certificates),
containerd's root (images, container metadata), ``/var/lib/cni``, the logs. The node's network
(its netns, veth, emulated link) is the machine's NIC and the network beyond: it stays.
"""

from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import dataclass

from e2e.bed import cgroups
from e2e.bed.base import HarnessError, log
from e2e.bed.processes import _proc_starttime, _stop
from e2e.bed.realnodes import RealNode, boot

__all__ = ["COMPONENTS", "Rebooted", "Restarted", "pids", "reboot", "restart"]

COMPONENTS = ("containerd", "kubelet", "kube-proxy", "kube-router")


@dataclass(frozen=True)
class Restarted:
    node: str
    component: str
    old_pid: int
    new_pid: int
    seconds: float  # from the signal until the nodehost recorded the new process


@dataclass(frozen=True)
class Rebooted:
    node: str
    killed: int  # processes killed in the node's cgroups
    down_seconds: float  # from the kill until the new nodehost started
    boot_seconds: float  # from the new nodehost's start until its containerd answered


def _table(node: RealNode) -> dict[str, dict[str, object]]:
    try:
        table: dict[str, dict[str, object]] = json.loads((node.dir / "pids.json").read_text())
    except (OSError, ValueError):
        return {}
    return table


def pids(node: RealNode) -> dict[str, int]:
    """The node's nodehost and components that run now, name -> pid (each pid checked
    against the start time recorded with it)."""
    return {
        name: int(str(rec["pid"]))
        for name, rec in _table(node).items()
        if _proc_starttime(int(str(rec["pid"]))) == rec.get("starttime")
    }


def restart(
    node: RealNode, component: str, sig: int = signal.SIGTERM, timeout: float = 30
) -> Restarted:
    """Stop one component of the node by its pid; return once the nodehost runs a new one."""
    if component not in COMPONENTS:
        raise HarnessError(f"unknown node component {component!r}: one of {', '.join(COMPONENTS)}")
    old = pids(node).get(component)
    if old is None:
        raise HarnessError(f"{node.name}: no running {component} in {node.dir / 'pids.json'}")
    t0 = time.monotonic()
    os.kill(old, sig)
    log(f"{node.name}: sent {signal.Signals(sig).name} to {component} pid {old}")
    while True:
        new = pids(node).get(component)
        if new is not None and new != old:
            took = time.monotonic() - t0
            log(f"{node.name}: {component} running again as pid {new} after {took:.1f}s")
            return Restarted(node.name, component, old, new, took)
        if time.monotonic() - t0 > timeout:
            raise HarnessError(
                f"{node.name}: {component} not restarted {timeout:.0f}s after pid {old}"
            )
        time.sleep(0.1)


def reboot(node: RealNode, down_seconds: float = 0.0) -> Rebooted:
    """Power-cycle the node: SIGKILL every process in its cgroups at once (nothing stops
    cleanly), stay down ``down_seconds``, then boot it as ``harness.py up`` did."""
    if "nodehost" not in pids(node):
        raise HarnessError(f"{node.name}: its nodehost is not running; nothing to reboot")
    t0 = time.monotonic()
    killed = cgroups.kill_all(cgroups.node_path(node.name))
    _stop(node.process_name)  # only forgets its pid record (a zombie at most is left)
    (node.dir / "pids.json").unlink(missing_ok=True)
    log(f"{node.name}: killed {killed} processes in {cgroups.node_path(node.name)}")
    time.sleep(max(0.0, down_seconds - (time.monotonic() - t0)))
    booted = time.monotonic()
    boot(node)
    up = time.monotonic()
    log(f"{node.name}: booted again, containerd up {up - booted:.1f}s after the boot")
    return Rebooted(node.name, killed, booted - t0, up - booted)
