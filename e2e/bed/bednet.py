"""The bed's network: one bridge the harness owns, one network namespace per real node.

    host netns                 node netns ``ffn-<node>``
    ffbr0 198.18.0.1/24  <-->  eth0 198.18.0.<10+i>/24   (veth ffv<i> on the host side)
                               cni0 198.18.<16+i>.1/24   (the node's pods, made by CNI)

Addresses come from the benchmarking range 198.18.0.0/15 (RFC 2544); services use
198.19.0.0/16. Nothing in the bed has a default route: a node routes the other nodes' pod
ranges through their eth0 addresses, the host routes each pod range through its node, and
pods route only 198.18.0.0/15. Multicast never leaves a node (dropped on its eth0), so DDS
discovery stays inside the node it started on. Everything here is undone by `teardown()`.
"""

from __future__ import annotations

import contextlib
import ipaddress
import subprocess
from dataclasses import dataclass
from pathlib import Path

from e2e.bed.base import HarnessError, log, run

BRIDGE = "ffbr0"
BRIDGE_IP = "198.18.0.1"
BRIDGE_PREFIX = 24
BED_RANGE = "198.18.0.0/15"
SERVICE_CIDR = "198.19.0.0/16"
KUBERNETES_SERVICE_IP = "198.19.0.1"
DNS_SERVICE_IP = "198.19.0.10"  # kube-system/kube-dns: CoreDNS (clusterservices.py)
NETNS_PREFIX = "ffn-"
VETH_PREFIX = "ffv"
MULTICAST = "224.0.0.0/4"
MAX_NODES = 200


@dataclass(frozen=True)
class NodeAddresses:
    """Where real node number `index` (1-based) lives on the bed's network."""

    name: str
    index: int

    def __post_init__(self) -> None:
        if not 1 <= self.index <= MAX_NODES:
            raise HarnessError(f"real node {self.name}: index {self.index} not in 1..{MAX_NODES}")

    @property
    def netns(self) -> str:
        return f"{NETNS_PREFIX}{self.name}"

    @property
    def host_veth(self) -> str:
        return f"{VETH_PREFIX}{self.index}"

    @property
    def node_veth(self) -> str:
        return "eth0"

    @property
    def ip(self) -> str:
        return f"198.18.0.{10 + self.index}"

    @property
    def pod_cidr(self) -> str:
        return f"198.18.{16 + self.index}.0/24"

    @property
    def pod_gateway(self) -> str:
        return f"198.18.{16 + self.index}.1"


def _ip(*args: str, netns: str | None = None) -> str:
    prefix = ["ip", "netns", "exec", netns] if netns else []
    return run([*prefix, "ip", *args], hint="hint: the bed needs root and iproute2")


def _exists(kind: str, name: str) -> bool:
    if kind == "netns":
        return Path("/run/netns", name).exists()
    return Path("/sys/class/net", name).exists()


def bridge_exists() -> bool:
    """Whether the bridge is there (the bed runs real nodes)."""
    return Path(f"/sys/class/net/{BRIDGE}").exists()


def ensure_bridge() -> None:
    """The host side: bridge ffbr0 with 198.18.0.1/24 (idempotent)."""
    if not _exists("link", BRIDGE):
        _ip("link", "add", BRIDGE, "type", "bridge")
        log(f"bednet: created bridge {BRIDGE}")
    addrs = _ip("-o", "-4", "addr", "show", "dev", BRIDGE)
    if f"{BRIDGE_IP}/{BRIDGE_PREFIX}" not in addrs:
        _ip("addr", "add", f"{BRIDGE_IP}/{BRIDGE_PREFIX}", "dev", BRIDGE)
    _ip("link", "set", BRIDGE, "up")


def add_node(node: NodeAddresses, peers: list[NodeAddresses]) -> None:
    """Create the node's namespace, its veth on the bridge, addresses and routes (idempotent)."""
    ensure_bridge()
    ns = node.netns
    if not _exists("netns", ns):
        _ip("netns", "add", ns)
    if not _exists("link", node.host_veth):
        tmp = f"ffp{node.index}"
        _ip("link", "add", node.host_veth, "type", "veth", "peer", "name", tmp)
        _ip("link", "set", tmp, "netns", ns)
        _ip("link", "set", tmp, "name", node.node_veth, netns=ns)
        _ip("link", "set", node.host_veth, "master", BRIDGE)
        _ip("link", "set", node.host_veth, "up")
    _ip("link", "set", "lo", "up", netns=ns)
    addrs = _ip("-o", "-4", "addr", "show", "dev", node.node_veth, netns=ns)
    if f"{node.ip}/{BRIDGE_PREFIX}" not in addrs:
        _ip("addr", "add", f"{node.ip}/{BRIDGE_PREFIX}", "dev", node.node_veth, netns=ns)
    _ip("link", "set", node.node_veth, "up", netns=ns)
    run(["ip", "netns", "exec", ns, "sysctl", "-q", "-w", "net.ipv4.ip_forward=1"])
    for peer in peers:
        if peer.index != node.index:
            _ip("route", "replace", peer.pod_cidr, "via", peer.ip, netns=ns)
    _ip("route", "replace", node.pod_cidr, "via", node.ip, "dev", BRIDGE)
    _drop_multicast(ns, node.node_veth)


def _drop_multicast(netns: str, dev: str) -> None:
    """No multicast leaves the node: DDS discovery stays inside it (unicast servers cross)."""
    for chain in ("OUTPUT", "FORWARD"):
        rule = ["-o", dev, "-d", MULTICAST, "-j", "DROP"]
        check = subprocess.run(
            ["ip", "netns", "exec", netns, "iptables", "-C", chain, *rule],
            capture_output=True,
            check=False,
        )
        if check.returncode != 0:
            run(["ip", "netns", "exec", netns, "iptables", "-A", chain, *rule])


def remove_node(node: NodeAddresses) -> None:
    with contextlib.suppress(HarnessError):
        _ip("route", "del", node.pod_cidr)
    if _exists("link", node.host_veth):
        with contextlib.suppress(HarnessError):
            _ip("link", "del", node.host_veth)
    if _exists("netns", node.netns):
        with contextlib.suppress(HarnessError):
            _ip("netns", "del", node.netns)


def teardown() -> None:
    """Remove every namespace, veth and the bridge the bed made (found by their prefixes)."""
    netns_dir = Path("/run/netns")
    names = sorted(p.name for p in netns_dir.glob(f"{NETNS_PREFIX}*")) if netns_dir.exists() else []
    for name in names:
        with contextlib.suppress(HarnessError):
            _ip("netns", "del", name)
    for link in sorted(Path("/sys/class/net").glob(f"{VETH_PREFIX}*")):
        if link.name[len(VETH_PREFIX) :].isdigit():
            with contextlib.suppress(HarnessError):
                _ip("link", "del", link.name)
    for route in _ip("-o", "-4", "route", "show").splitlines():
        dst = route.split()[0]
        if dst != "default" and _in_bed(dst) and f"dev {BRIDGE}" in route and " via " in route:
            with contextlib.suppress(HarnessError):
                _ip("route", "del", dst)
    if _exists("link", BRIDGE):
        _ip("link", "del", BRIDGE)
        log(f"bednet: removed bridge {BRIDGE} and {len(names)} node namespaces")
    # `ip netns add` made /run/netns a mount of its own; give it back when nothing is in it
    if netns_dir.is_dir() and not any(netns_dir.iterdir()):
        subprocess.run(["umount", str(netns_dir)], capture_output=True, check=False)
        with contextlib.suppress(OSError):
            netns_dir.rmdir()


def _in_bed(cidr: str) -> bool:
    try:
        return ipaddress.ip_network(cidr, strict=False).subnet_of(ipaddress.ip_network(BED_RANGE))
    except ValueError:
        return False
