"""Slower fake-node heartbeats for scale runs, and the bed's own back afterwards.

The bed's kwok renews every fake node's Lease every 2.5 s (``NODE_LEASE_SECONDS`` / 4) so the
node-failure tests see a failure within seconds. At hundreds of fake nodes those renewals
alone are hundreds of writes a second on the control plane's two cores: at 300 robots (420
nodes) kwok fell behind, the Leases expired and the node-lifecycle controller tainted every
node (2026-11-23). A scale benchmark measures the operator, not node-failure detection, so it
runs with heartbeats as slow as a large production cluster's: ``relaxed`` restarts kwok and
kube-controller-manager with a longer Lease and grace period and restores the bed's on exit.
``restore`` puts the bed's back if a run died before it could (``bed.ensure_up`` calls it).
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict

from e2e.bed.base import STATE_DIR, HarnessError, locked, log, port_is_free, wait_for
from e2e.bed.cluster import HEARTBEAT_LABEL, Cluster, _read_state
from e2e.bed.controlplane import Heartbeats, _argv, _wait_healthy
from e2e.bed.processes import _start, _stop

# what a scale run uses: kwok renews each Lease every 30 s (~47 writes a second at 1400 nodes,
# where the bed's 2.5 s would be 560), and a node is NotReady only after 4 missed renewals
SCALE = Heartbeats(lease_seconds=120, grace_period="120s")
_FILE = STATE_DIR / "heartbeats.json"
_COMPONENTS = ("kube-controller-manager", "kwok")


def current() -> Heartbeats:
    """The heartbeats the running bed was (re)started with."""
    try:
        return Heartbeats(**json.loads(_FILE.read_text()))
    except (OSError, ValueError, TypeError):
        return Heartbeats()


def _switch(to: Heartbeats) -> None:
    """Restart kwok and kube-controller-manager with ``to``. Never a moment where a Lease
    renewed at the old pace is judged at a shorter grace period: relaxing, the controller
    manager's grace grows first; restoring, kwok renews every Lease at the short pace first."""
    state = _read_state()
    if not state or state.get("phase") != "running":
        raise HarnessError("the bed is not running (make cluster-up)")
    ports = state["ports"]
    argv = _argv(ports, to)
    old = current()
    shorter = to.lease_seconds < old.lease_seconds
    order = ("kwok", "kube-controller-manager") if shorter else _COMPONENTS
    for name in order:
        _stop(name)
        _wait_port_free(name, ports[name])
        _start(name, *argv[name])
        _wait_healthy(name, ports)
        if name == "kwok" and shorter:
            # kwok's new run takes a Lease over only once its old run's expires
            _wait_renewed(
                Cluster.from_state(state), to.lease_seconds / 4 + 1.0, old.lease_seconds + 60.0
            )
    if to == Heartbeats():
        _FILE.unlink(missing_ok=True)
    else:
        _FILE.write_text(json.dumps(asdict(to)) + "\n")
    log(f"fake-node Leases of {to.lease_seconds}s, NotReady after {to.grace_period}")


def _wait_port_free(name: str, port: int) -> None:
    """A stopped Go server may hold its port a moment after it counts as gone (its main thread is
    a zombie while its other threads still close their sockets): a new one started then fails
    to bind, and its health check passes against the old one (CI, 2026-11-26: the controller
    manager was left down and every namespace's default ServiceAccount with it)."""
    wait_for(f"{name}'s port {port} free", lambda: port_is_free(port), 30, interval=0.1)


def _wait_renewed(cluster: Cluster, within: float, timeout: float) -> None:
    """Until the Lease of every node kwok heartbeats was renewed in the last ``within`` s."""
    nodes = cluster.kubectl_json("get", "nodes")["items"]
    fake = {
        n["metadata"]["name"]
        for n in nodes
        if (n["metadata"].get("annotations") or {}).get("kwok.x-k8s.io/node") == "fake"
        and (n["metadata"].get("labels") or {}).get(HEARTBEAT_LABEL) != "stopped"
    }

    def fresh() -> bool:
        leases = cluster.kubectl_json("get", "leases", "-n", "kube-node-lease")["items"]
        now = datetime.datetime.now(datetime.UTC)
        for lease in (x for x in leases if x["metadata"]["name"] in fake):
            renew = lease["spec"].get("renewTime")
            if renew is None:
                return False
            at = datetime.datetime.fromisoformat(renew.replace("Z", "+00:00"))
            if (now - at).total_seconds() > within:
                return False
        return True

    wait_for("every node Lease renewed at the bed's pace", fresh, timeout, interval=1.0)


def restore() -> None:
    """The bed's own heartbeats, if a scale run left others behind (caller holds the lock)."""
    if current() != Heartbeats():
        _switch(Heartbeats())


@contextmanager
def relaxed(to: Heartbeats = SCALE) -> Iterator[Heartbeats]:
    """Run the body with ``to``'s heartbeats; the bed's come back however the body ends."""
    with locked():
        _switch(to)
    try:
        yield to
    finally:
        with locked():
            _switch(Heartbeats())
