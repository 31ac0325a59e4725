"""The cloud as a second cluster (issue 47; MULTICLUSTER.md): a control plane of its own beside
the bed's, which Open Cluster Management joins to it (``ocm``).

    python e2e/bed/harness.py up --cloud      (make cluster-up CLOUD=1)

- **Its own API**: a kube-apiserver on its own loopback port, with a CA, serving and admin
  certificates and a service-account key of its own, so that nothing signed by one cluster is
  trusted by the other. It stores in the bed's etcd under a prefix of its own (``/cloud/<its
  start>``): the two clusters share no object, and a 2-core machine runs one etcd less.
- **A kube-controller-manager** that signs certificate requests (OCM's agents register by
  them, as kubelets do), and runs the namespace, service-account and garbage collectors.
- **The WAN**: the site reaches the cloud only through ``wan.py``, a relay on loopback that
  delays (20 ms each way), paces (50 Mbit/s) and can be cut (``set_wan``): the site's OCM
  agent reaches the hub's API across it, and the site's Zenoh router the cloud's
  (``routers.py``, ROS 2's data across the WAN); the cloud's own agent reaches its API directly.
- **Its machines**: kwok's nodes (``NODES``, tier ``cloud``), with a kube-scheduler that binds
  pods to them, so that the cloud has a capacity OCM reports and Deployments that become
  Available; nothing runs inside them. On a bed with real nodes, ``start_node`` adds one real
  node (``NODE``): containerd and a kubelet in a network namespace of the bed's bridge, a
  member of the cloud's cluster (its CA, its API through a gateway on the bridge), with the
  workload image, so that a cloud instance's pod really runs in the cloud; its relay sidecar
  reaches the cloud's router on the bridge, and from there the site only across the WAN.

Everything listens on 127.0.0.1; its processes are the bed's (``processes``: stopped by pid,
logs beside the others), and ``bed.down`` stops them with the rest.
"""

from __future__ import annotations

import json
import os
import signal
import ssl
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from e2e.bed import realnodes
from e2e.bed.base import (
    BIN_DIR,
    HERE,
    HOST,
    STATE_DIR,
    HarnessError,
    answers,
    free_port,
    insecure_tls,
    kubectl,
    log,
    port_is_free,
    wait_for,
)
from e2e.bed.bednet import BRIDGE_IP, bridge_exists
from e2e.bed.cluster import is_ok, probe
from e2e.bed.controlplane import (
    ALLOW_PATHS,
    _wait_healthy,
    kwok_argv,
    scheduler_argv,
    write_kwok_config,
    write_scheduler_config,
)
from e2e.bed.fakenodes import node_object, ready_nodes
from e2e.bed.pki import issue_cert, kubeconfig, make_ca
from e2e.bed.processes import _alive, _start, _stop

__all__ = [
    "CLOUD_DIR",
    "COMPONENTS",
    "CloudCluster",
    "WanSettings",
    "running",
    "set_wan",
    "start",
    "start_node",
    "stop",
    "stop_node",
]

CLOUD_DIR = STATE_DIR / "cloud"
PKI = CLOUD_DIR / "pki"
STATE_FILE = CLOUD_DIR / "state.json"
KUBECONFIG = CLOUD_DIR / "kubeconfig"
ETCD_PREFIX = "/cloud"  # and a start's own key below it: each start is a new cluster
# the cloud's Service range: apart from the site's (bednet.SERVICE_CIDR), as two clusters' are
SERVICE_CIDR = "10.97.0.0/16"
APISERVER, CONTROLLER_MANAGER = "cloud-kube-apiserver", "cloud-kube-controller-manager"
SCHEDULER, KWOK = "cloud-kube-scheduler", "cloud-kwok"
WAN = "site-cloud-wan"  # the relay the site reaches the cloud through (``wan.py``)
WAN_ZENOH = "wan-zenoh"  # the WAN's second port (ports only): the cloud's router, from the site
# The Zenoh routers (``routers.py``): the cloud's listens, the site's dials it across the WAN
CLOUD_ROUTER, SITE_ROUTER = "cloud-zenoh-router", "site-zenoh-router"
COMPONENTS = (APISERVER, CONTROLLER_MANAGER, SCHEDULER, KWOK, CLOUD_ROUTER, WAN, SITE_ROUTER)
WAN_SETTINGS = CLOUD_DIR / "wan.json"
# The WAN's one-way delay and rate: a round trip of 40 ms, 50 Mbit/s (issue 47's example; a
# cloud region one country away)
WAN_DELAY_MS, WAN_RATE_MBIT = 20.0, 50.0
# The cloud's nodes: kwok's, for capacity (a cloud region's machines; nothing runs in them).
NODES = tuple(f"cloud-vm-{i}" for i in (1, 2))
NODE_CPU, NODE_MEMORY_GI, NODE_HARDWARE = 16, 64, "fsv2-16"
KWOK_LEASE_SECONDS = 40  # kwok renews every 10 s: nothing here tests a cloud node's failure
# The cloud's one real node (``start_node``): a small VM of the cloud region, on the bed's
# bridge at an index no site profile uses, with room for one cloud instance and its sidecar
NODE = realnodes.RealNode(
    "cloud-node-1",
    50,
    {"fogfleet.io/tier": "cloud", "fogfleet.io/hardware-type": "cloud-vm"},
    1500,
    1536 * 2**20,
)
NODE_GATEWAY = "cloud-node-gateway"  # the cloud's API on the bridge, for its real node
START_TIMEOUT_S = 180


@dataclass(frozen=True)
class CloudCluster:
    """The running cloud cluster: where its API is and how to reach it as its admin."""

    api_server: str
    kubeconfig: Path
    ports: Mapping[str, int]

    @property
    def from_site(self) -> str:
        """The cloud's API as the site reaches it: across the WAN."""
        return f"https://{HOST}:{self.ports[WAN]}"

    @property
    def cloud_router(self) -> str:
        """The Zenoh endpoint of the cloud's router (what the cloud's modules connect to)."""
        return f"tcp/{HOST}:{self.ports[CLOUD_ROUTER]}"

    @property
    def cloud_router_for_pods(self) -> str:
        """The cloud's router as the cloud's real node's pods reach it: on the bed's bridge
        (the ClusterClaim ``relay-router.fogfleet.io`` of a cloud that runs them)."""
        return f"tcp/{BRIDGE_IP}:{self.ports[CLOUD_ROUTER]}"

    @property
    def site_router(self) -> str:
        """The Zenoh endpoint of the site's router (what the site's modules connect to)."""
        return f"tcp/{HOST}:{self.ports[SITE_ROUTER]}"

    @property
    def site_router_for_pods(self) -> str:
        """The site's router as the real nodes' pods reach it: on the bed's bridge (what the
        site's operator gives the robots' relays, FOGFLEET_SITE_ROUTER)."""
        return f"tcp/{BRIDGE_IP}:{self.ports[SITE_ROUTER]}"

    def kubectl(self, *args: str, input: str | None = None, check: bool = True) -> str:
        return kubectl(BIN_DIR / "kubectl", self.kubeconfig, *args, input=input, check=check).stdout

    def healthy(self) -> bool:
        return all(_health(name, self.ports)[0] for name in COMPONENTS)

    def nodes_ready(self) -> bool:
        items = json.loads(self.kubectl("get", "nodes", "-o", "json"))["items"]
        return set(NODES) <= ready_nodes(items)


def _health(name: str, ports: Mapping[str, int]) -> tuple[bool, str]:
    if name in (WAN, CLOUD_ROUTER, SITE_ROUTER):  # they listen (a cut WAN holds what crosses)
        listening = not port_is_free(ports[name])
        return listening, "listening" if listening else "not listening"
    if name == APISERVER:
        ctx = ssl.create_default_context(cafile=str(PKI / "ca.crt"))
        return probe(f"https://{HOST}:{ports[name]}/readyz", is_ok, ctx)
    return probe(f"https://{HOST}:{ports[name]}/healthz", is_ok, insecure_tls())


def running() -> CloudCluster | None:
    """The cloud cluster if its state is there and every process of it is up and healthy."""
    try:
        state: dict[str, Any] = json.loads(STATE_FILE.read_text())
    except (OSError, ValueError):
        return None
    cloud = CloudCluster(state["api_server"], KUBECONFIG, state["ports"])
    if any(_alive(name) is None for name in COMPONENTS) or not cloud.healthy():
        return None
    return cloud


def _make_pki() -> None:
    make_ca(PKI, "fogfleet-cloud-ca")
    sans = [f"IP:{HOST}", "DNS:localhost", f"IP:{BRIDGE_IP}"]  # the bridge: the real node's
    issue_cert("admin", "/O=system:masters/CN=fogfleet-cloud-admin", sans, pki=PKI)


def _argv(ports: Mapping[str, int], etcd_url: str, prefix: str) -> dict[str, list[str]]:
    kc = str(KUBECONFIG)
    return {
        SCHEDULER: scheduler_argv(KUBECONFIG, CLOUD_DIR, ports[SCHEDULER]),
        WAN: [
            sys.executable,
            str(HERE / "wan.py"),
            f"--route={HOST}:{ports[WAN]}={HOST}:{ports[APISERVER]}",
            f"--route={HOST}:{ports[WAN_ZENOH]}={HOST}:{ports[CLOUD_ROUTER]}",
            f"--settings={WAN_SETTINGS}",
        ],
        CLOUD_ROUTER: [
            sys.executable,
            str(HERE / "routers.py"),
            f"--listen=tcp/{HOST}:{ports[CLOUD_ROUTER]}",
            *([f"--listen=tcp/{BRIDGE_IP}:{ports[CLOUD_ROUTER]}"] if bridge_exists() else []),
        ],
        SITE_ROUTER: [
            sys.executable,
            str(HERE / "routers.py"),
            f"--listen=tcp/{HOST}:{ports[SITE_ROUTER]}",
            *([f"--listen=tcp/{BRIDGE_IP}:{ports[SITE_ROUTER]}"] if bridge_exists() else []),
            f"--connect=tcp/{HOST}:{ports[WAN_ZENOH]}",
        ],
        KWOK: kwok_argv(KUBECONFIG, CLOUD_DIR, PKI, ports[KWOK], KWOK_LEASE_SECONDS),
        APISERVER: [
            str(BIN_DIR / "kube-apiserver"),
            f"--etcd-servers={etcd_url}",
            f"--etcd-prefix={prefix}",
            f"--bind-address={HOST}",
            f"--secure-port={ports[APISERVER]}",
            f"--advertise-address={HOST}",
            "--endpoint-reconciler-type=none",
            f"--tls-cert-file={PKI / 'admin.crt'}",
            f"--tls-private-key-file={PKI / 'admin.key'}",
            f"--client-ca-file={PKI / 'ca.crt'}",
            "--service-account-issuer=https://kubernetes.default.svc.cloud.local",
            f"--service-account-key-file={PKI / 'sa.key'}",
            f"--service-account-signing-key-file={PKI / 'sa.key'}",
            f"--service-cluster-ip-range={SERVICE_CIDR}",
            "--authorization-mode=Node,RBAC",
            f"--cert-dir={CLOUD_DIR / 'certs'}",
        ],
        CONTROLLER_MANAGER: [
            str(BIN_DIR / "kube-controller-manager"),
            f"--kubeconfig={kc}",
            f"--authentication-kubeconfig={kc}",
            f"--authorization-kubeconfig={kc}",
            f"--bind-address={HOST}",
            f"--secure-port={ports[CONTROLLER_MANAGER]}",
            ALLOW_PATHS,
            "--leader-elect=false",
            f"--root-ca-file={PKI / 'ca.crt'}",
            f"--service-account-private-key-file={PKI / 'sa.key'}",
            f"--cluster-signing-cert-file={PKI / 'ca.crt'}",
            f"--cluster-signing-key-file={PKI / 'ca.key'}",
            # kwok's nodes need no CIDR, route or cloud provider; node lifecycle stays (it takes
            # the not-ready taint off a node that turns Ready)
            "--controllers=*,-nodeipam,-cloud-node-lifecycle,-route,-service",
            f"--cert-dir={CLOUD_DIR / 'certs' / 'kcm'}",
        ],
    }


def start(etcd_url: str) -> CloudCluster:
    """Start the cloud cluster's control plane against the bed's etcd (``etcd_url``), or
    return it when it already runs healthy. Returns once its API is ready."""
    cloud = running()
    if cloud is not None:
        log(f"cloud cluster: already running ({cloud.api_server})")
        return cloud
    stop()
    t0 = time.monotonic()
    ports = {name: free_port() for name in (*COMPONENTS, WAN_ZENOH)}
    while len(set(ports.values())) < len(ports):  # free_port may hand the same port twice
        ports = {name: free_port() for name in (*COMPONENTS, WAN_ZENOH)}
    CLOUD_DIR.mkdir(parents=True, exist_ok=True)
    _make_pki()
    api_server = f"https://{HOST}:{ports[APISERVER]}"
    KUBECONFIG.write_text(
        kubeconfig(api_server, "fogfleet-cloud-admin", PKI / "admin.crt", PKI / "admin.key",
                   ca=PKI / "ca.crt")
    )  # fmt: skip
    KUBECONFIG.chmod(0o600)
    # a new CA, so a new cluster: nothing the last one stored is read again (it stays in the
    # bed's etcd until the bed's data directory goes)
    prefix = f"{ETCD_PREFIX}/{int(time.time())}"
    write_scheduler_config(KUBECONFIG, CLOUD_DIR)
    write_kwok_config(CLOUD_DIR)
    WAN_SETTINGS.write_text(json.dumps(WanSettings().as_json()) + "\n")
    argv = _argv(ports, etcd_url, prefix)
    env = {KWOK: dict(os.environ, KWOK_WORKDIR=str(CLOUD_DIR / "kwok"))}
    cloud = CloudCluster(api_server, KUBECONFIG, ports)
    try:
        for name in COMPONENTS:
            _start(name, argv[name], env.get(name))
            _wait_healthy(name, ports, _health, START_TIMEOUT_S)
        nodes = [node_object(n, "cloud", NODE_HARDWARE, NODE_CPU, NODE_MEMORY_GI) for n in NODES]
        cloud.kubectl("apply", "-f", "-", input=json.dumps({"apiVersion": "v1", "kind": "List",
                                                            "items": nodes}))  # fmt: skip
        wait_for(f"the cloud's {len(NODES)} nodes Ready", cloud.nodes_ready, START_TIMEOUT_S)
    except BaseException:
        log(f"cloud cluster: start-up failed; stopping what started (logs in {STATE_DIR / 'logs'})")
        stop()
        raise
    STATE_FILE.write_text(
        json.dumps({"api_server": api_server, "ports": ports, "etcd_prefix": prefix}) + "\n"
    )
    log(f"cloud cluster: control plane up in {time.monotonic() - t0:.1f}s ({api_server})")
    return cloud


@dataclass(frozen=True)
class WanSettings:
    """The WAN between the site and the cloud: one-way delay, rate, and whether it is cut."""

    delay_ms: float = WAN_DELAY_MS
    rate_mbit: float = WAN_RATE_MBIT
    cut: bool = False

    def as_json(self) -> dict[str, Any]:
        return {"delay_ms": self.delay_ms, "rate_mbit": self.rate_mbit, "cut": self.cut}


def set_wan(settings: WanSettings) -> None:
    """Change the running WAN (a cut holds what crosses until ``cut`` is False again)."""
    pid = _alive(WAN)
    if pid is None:
        raise HarnessError("the cloud's WAN relay is not running (harness.py up --cloud)")
    WAN_SETTINGS.write_text(json.dumps(settings.as_json()) + "\n")
    os.kill(pid, signal.SIGHUP)
    log(f"cloud WAN: {'CUT' if settings.cut else 'up'}, {settings.delay_ms:g} ms one way, "
        f"{settings.rate_mbit:g} Mbit/s")  # fmt: skip


def start_node(cloud: CloudCluster, images: Sequence[Path]) -> None:
    """The cloud's real node (``NODE``, module docstring) started with ``images`` and Ready
    in the cloud's cluster; a node whose processes already run is left alone."""
    kubectl_ = partial(kubectl, BIN_DIR / "kubectl", KUBECONFIG)
    port = cloud.ports[APISERVER]
    if _alive(NODE.process_name) is not None and _alive(NODE_GATEWAY) is not None:
        return
    t0 = time.monotonic()
    _start(NODE_GATEWAY, [sys.executable, str(HERE / "gateway.py"),
                          f"{BRIDGE_IP}:{port}={HOST}:{port}"])  # fmt: skip
    wait_for(f"the cloud's gateway on {BRIDGE_IP}:{port}", partial(answers, BRIDGE_IP, port), 20)
    member = realnodes.Membership(f"https://{BRIDGE_IP}:{port}", PKI, services=False)
    realnodes.start([NODE], member, images)
    realnodes.wait_ready(kubectl_, [NODE.name])
    log(f"cloud cluster: real node {NODE.name} Ready in {time.monotonic() - t0:.1f}s")


def stop_node() -> None:
    """Stop the cloud's real node and its gateway (nothing of the site's nodes)."""
    if _alive(NODE.process_name) is not None or NODE.dir.exists():
        realnodes.stop_one(NODE)
    _stop(NODE_GATEWAY)


def stop() -> None:
    """Stop the cloud cluster's processes (by pid) and remove its state. Its objects in the
    bed's etcd go with the bed's data directory."""
    stop_node()
    for name in reversed(COMPONENTS):
        _stop(name)
    STATE_FILE.unlink(missing_ok=True)
