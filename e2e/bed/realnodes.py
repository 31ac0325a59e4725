"""Real nodes: one containerd, one kubelet, one kube-proxy and one kube-router (only its
NetworkPolicy firewall) per node, each node a small host.

A real node is declared in ``nodes.yaml`` beside the kwok nodes (the ``default`` bed profile)
or in a profile's own file (``nodes-<profile>.yaml``, real nodes only: ``PROFILES``), as a
Node document with the annotation ``fogfleet.io/e2e-real: "true"`` and its bed settings::

    fogfleet.io/e2e-cpu: 400m          # CFS quota of the node's cgroup (its share of this machine)
    fogfleet.io/e2e-memory: 1536Mi     # memory limit of the node's cgroup
    fogfleet.io/e2e-link: '{"type": "wifi", "latencyMillis": 4, "jitterMillis": 1, ...}'

The kubelet registers the Node under the document's name with the document's labels, and
advertises the share as allocatable (systemReserved = machine - share). kwok only manages
nodes annotated ``kwok.x-k8s.io/node: fake``, so it leaves these alone.

Layout of a node (see bednet.py for its network, cgroups.py for its size, nodehost.py for
what runs inside its namespaces)::

    STATE_DIR/nodes/<node>/  nodehost.json  containerd.toml  containerd.sock  containerd/
                             kubelet.json  kubelet.kubeconfig  kube-proxy.json
                             kube-router.kubeconfig  pki/ logs/
                             kubelet/ (= /var/lib/kubelet inside)  pod-logs/ cni-conf/ cni/
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from e2e.bed import bednet, cgroups
from e2e.bed.base import BIN_DIR, HERE, NODES_FILE, STATE_DIR, HarnessError, log, run, wait_for
from e2e.bed.bednet import NodeAddresses
from e2e.bed.clusterservices import CLUSTER_DOMAIN
from e2e.bed.links import LinkSpec, apply_link, stop_link
from e2e.bed.pki import issue_cert, kubeconfig
from e2e.bed.processes import _alive, _start, _stop, log_tail

REAL_ANNOTATION = "fogfleet.io/e2e-real"
CPU_ANNOTATION = "fogfleet.io/e2e-cpu"
MEMORY_ANNOTATION = "fogfleet.io/e2e-memory"
LINK_ANNOTATION = "fogfleet.io/e2e-link"
PAUSE_IMAGE = "localhost/fogfleet/pause:3.10"
CNI_BIN_DIR = "/usr/lib/cni"
CTR = "ctr"
NODES_DIR = STATE_DIR / "nodes"
# Bed profiles: which real nodes a bed runs. ``default`` is the e2e suite's bed (nodes.yaml);
# ``paper`` is the paper's real-robot experiment (IV-C) scaled by 15: two Raspberry Pi 4
# robots and two unequal i9 edge servers (e2e/bench/real/paper/nodes.yaml says how).
# ``kwok`` has none: the control plane and the kwok nodes only, for benchmarks at scale.
PROFILES = {
    "default": NODES_FILE,
    "paper": HERE / "nodes-paper.yaml",
    "kwok": HERE / "nodes-kwok.yaml",
}
DEFAULT_PROFILE = "default"
CREATED_MOUNTPOINTS = STATE_DIR / "created-mountpoints.json"
# Paths containerd and the kubelet hard-code: private per node (tmpfs or a bind of its dir).
TMPFS_PATHS = ("/run/containerd", "/run/netns")
BIND_PATHS = {
    "kubelet": "/var/lib/kubelet",
    "pod-logs": "/var/log/pods",
    "container-logs": "/var/log/containers",
    "cni-conf": "/etc/cni/net.d",
    "cni": "/var/lib/cni",
}
NODE_READY_TIMEOUT = 120
# What kube-router's firewall reads (its informers also watch Services and Endpoints).
KUBE_ROUTER_USER = "system:kube-router"
KUBE_ROUTER_RBAC: list[dict[str, Any]] = [
    {
        "apiVersion": "rbac.authorization.k8s.io/v1",
        "kind": "ClusterRole",
        "metadata": {"name": "fogfleet-bed:kube-router"},
        "rules": [
            {
                "apiGroups": [""],
                "resources": ["pods", "namespaces", "nodes", "services", "endpoints"],
                "verbs": ["get", "list", "watch"],
            },
            {
                "apiGroups": ["networking.k8s.io"],
                "resources": ["networkpolicies"],
                "verbs": ["get", "list", "watch"],
            },
            {
                "apiGroups": ["discovery.k8s.io"],
                "resources": ["endpointslices"],
                "verbs": ["get", "list", "watch"],
            },
            {
                "apiGroups": ["", "events.k8s.io"],
                "resources": ["events"],
                "verbs": ["create", "patch"],
            },
        ],
    },
    {
        "apiVersion": "rbac.authorization.k8s.io/v1",
        "kind": "ClusterRoleBinding",
        "metadata": {"name": "fogfleet-bed:kube-router"},
        "roleRef": {
            "apiGroup": "rbac.authorization.k8s.io",
            "kind": "ClusterRole",
            "name": "fogfleet-bed:kube-router",
        },
        "subjects": [
            {"apiGroup": "rbac.authorization.k8s.io", "kind": "User", "name": KUBE_ROUTER_USER}
        ],
    },
]


@dataclass(frozen=True)
class RealNode:
    """One real node as declared in nodes.yaml."""

    name: str
    index: int
    labels: dict[str, str]
    cpu_millis: int
    memory_bytes: int
    link: dict[str, Any] = field(default_factory=dict)

    @property
    def net(self) -> NodeAddresses:
        return NodeAddresses(self.name, self.index)

    @property
    def dir(self) -> Path:
        return NODES_DIR / self.name

    @property
    def socket(self) -> Path:
        return self.dir / "containerd.sock"

    @property
    def process_name(self) -> str:
        return f"node-{self.name}"

    @property
    def cgroup(self) -> str:
        return cgroups.node_path(self.name)


@dataclass(frozen=True)
class Membership:
    """The cluster a real node joins: its API as the node reaches it, the directory of the CA
    that signs the node's certificates (and whose clients its kubelet trusts), and whether
    the cluster's services run beside the kubelet (kube-proxy, kube-router's firewall and
    cluster DNS: the site's). The cloud's node (``cloud``) runs containerd and the kubelet
    only."""

    api_server: str
    pki: Path = STATE_DIR / "pki"
    services: bool = True


def _quantity_millis(text: str) -> int:
    return int(text[:-1]) if text.endswith("m") else int(float(text) * 1000)


def _quantity_bytes(text: str) -> int:
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30}
    for suffix, factor in units.items():
        if text.endswith(suffix):
            return int(float(text[: -len(suffix)]) * factor)
    return int(text)


def split_manifest(text: str) -> tuple[list[dict[str, Any]], list[RealNode]]:
    """The fake Node documents (for kubectl apply) and the real nodes of a nodes.yaml."""
    import yaml  # the project's dependency; every entry point runs in its venv

    fake: list[dict[str, Any]] = []
    real: list[RealNode] = []
    for doc in yaml.safe_load_all(text):
        if not doc:
            continue
        meta = doc.get("metadata", {})
        ann = meta.get("annotations") or {}
        if str(ann.get(REAL_ANNOTATION, "")).lower() != "true":
            fake.append(doc)
            continue
        name = meta["name"]
        try:
            node = RealNode(
                name=name,
                index=len(real) + 1,
                labels={str(k): str(v) for k, v in (meta.get("labels") or {}).items()},
                cpu_millis=_quantity_millis(str(ann[CPU_ANNOTATION])),
                memory_bytes=_quantity_bytes(str(ann[MEMORY_ANNOTATION])),
                link=json.loads(ann.get(LINK_ANNOTATION, "{}")),
            )
        except (KeyError, ValueError) as exc:
            raise HarnessError(f"nodes.yaml: real node {name}: bad or missing {exc}") from exc
        real.append(node)
    return fake, real


def profile_nodes(profile: str) -> list[RealNode]:
    """The real nodes of a bed profile (``PROFILES``); an unknown one is refused by name."""
    if profile not in PROFILES:
        raise HarnessError(f"unknown bed profile {profile!r}: one of {', '.join(PROFILES)}")
    _, real = split_manifest(PROFILES[profile].read_text())
    return real


def declared(name: str) -> RealNode:
    """The real node `name` as its profile's file declares it (node names are unique across
    profiles, so the running bed's profile need not be known)."""
    for profile in PROFILES:
        for node in profile_nodes(profile):
            if node.name == name:
                return node
    raise HarnessError(f"no bed profile declares a real node {name!r}")


def set_link(node: RealNode, **change: float) -> LinkSpec:
    """Apply the node's declared link, with `change` (LinkSpec fields) on top."""
    spec = replace(LinkSpec.from_network(node.link), **change)
    return apply_link(node.net.netns, node.net.node_veth, node.net.host_veth, spec)


# --------------------------------------------------------------------------------------------
# configuration files


def _machine_memory_bytes() -> int:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) * 1024
    raise HarnessError("no MemTotal in /proc/meminfo")


def _machine_cpu_millis() -> int:
    import os

    return (os.cpu_count() or 1) * 1000


def _write_json(path: Path, obj: Any) -> Path:
    path.write_text(json.dumps(obj, indent=1) + "\n")
    return path


def _containerd_config(node: RealNode) -> str:
    return f"""version = 2
root = "{node.dir / "containerd"}"
state = "/run/containerd"
disabled_plugins = ["io.containerd.snapshotter.v1.btrfs", "io.containerd.snapshotter.v1.zfs",
  "io.containerd.snapshotter.v1.aufs", "io.containerd.snapshotter.v1.devmapper",
  "io.containerd.tracing.processor.v1.otlp", "io.containerd.internal.v1.tracing"]

[grpc]
  address = "{node.socket}"

[plugins."io.containerd.grpc.v1.cri"]
  sandbox_image = "{PAUSE_IMAGE}"
  # This VM withholds CAP_SYS_RESOURCE: runc cannot lower oom_score_adj (REALNODE.md).
  restrict_oom_score_adj = true
  disable_apparmor = true
  enable_selinux = false
  [plugins."io.containerd.grpc.v1.cri".containerd]
    snapshotter = "overlayfs"
    default_runtime_name = "runc"
    [plugins."io.containerd.grpc.v1.cri".containerd.runtimes.runc]
      runtime_type = "io.containerd.runc.v2"
  [plugins."io.containerd.grpc.v1.cri".cni]
    bin_dir = "{CNI_BIN_DIR}"
    conf_dir = "/etc/cni/net.d"
"""


def _cni_config(node: RealNode) -> dict[str, Any]:
    """Pods on a bridge inside the node, routed only within the bed (no default route)."""
    return {
        "cniVersion": "1.0.0",
        "name": "fogfleet-bed",
        "plugins": [
            {
                "type": "bridge",
                "bridge": "cni0",
                "isGateway": True,
                "isDefaultGateway": False,
                "ipMasq": False,
                "hairpinMode": True,
                "ipam": {
                    "type": "host-local",
                    "ranges": [[{"subnet": node.net.pod_cidr, "gateway": node.net.pod_gateway}]],
                    "routes": [{"dst": bednet.BED_RANGE}],
                    "dataDir": "/var/lib/cni/networks",
                },
            },
        ],
    }


def _kubelet_config(node: RealNode, pki: Path, member: Membership) -> dict[str, Any]:
    reserved_cpu = max(0, _machine_cpu_millis() - node.cpu_millis)
    reserved_mem = max(0, _machine_memory_bytes() - node.memory_bytes)
    return {
        "apiVersion": "kubelet.config.k8s.io/v1beta1",
        "kind": "KubeletConfiguration",
        "address": node.net.ip,
        "port": 10250,
        "readOnlyPort": 0,
        "healthzBindAddress": "127.0.0.1",
        "healthzPort": 10248,
        "authentication": {
            "anonymous": {"enabled": False},
            "webhook": {"enabled": True},
            "x509": {"clientCAFile": str(member.pki / "ca.crt")},
        },
        "authorization": {"mode": "Webhook"},
        "tlsCertFile": str(pki / "kubelet-serving.crt"),
        "tlsPrivateKeyFile": str(pki / "kubelet-serving.key"),
        # cgroup v1 without systemd (REALNODE.md). The QoS tree goes below the node's own
        # cgroup, so every pod is inside the node's CPU quota and memory limit (cgroups.py).
        "failCgroupV1": False,
        "cgroupDriver": "cgroupfs",
        "cgroupsPerQOS": True,
        "cgroupRoot": cgroups.node_path(node.name, "pods"),
        "enforceNodeAllocatable": [],
        "failSwapOn": False,
        # cluster DNS (clusterservices.py); the host's resolv.conf stays out of every pod
        "clusterDNS": [bednet.DNS_SERVICE_IP] if member.services else [],
        "clusterDomain": CLUSTER_DOMAIN,
        "resolvConf": "",
        "containerRuntimeEndpoint": f"unix://{node.socket}",
        "imageServiceEndpoint": f"unix://{node.socket}",
        "systemReserved": {"cpu": f"{reserved_cpu}m", "memory": str(reserved_mem)},
        "evictionHard": {"memory.available": "1%", "nodefs.available": "1%"},
        "imageGCHighThresholdPercent": 99,
        "imageGCLowThresholdPercent": 98,
        "nodeStatusUpdateFrequency": "2s",
        "nodeStatusReportFrequency": "10s",
        "nodeLeaseDurationSeconds": 10,
        "syncFrequency": "10s",
        "serializeImagePulls": False,
        "maxPods": 110,
        "podPidsLimit": 4096,
        "shutdownGracePeriod": "0s",
    }


def _kube_proxy_config(node: RealNode, kubeconfig_path: Path) -> dict[str, Any]:
    return {
        "apiVersion": "kubeproxy.config.k8s.io/v1alpha1",
        "kind": "KubeProxyConfiguration",
        "clientConnection": {"kubeconfig": str(kubeconfig_path)},
        "hostnameOverride": node.name,
        "mode": "iptables",
        "clusterCIDR": bednet.BED_RANGE,
        "healthzBindAddress": "127.0.0.1:10256",
        "metricsBindAddress": "127.0.0.1:10249",
        "nodePortAddresses": [f"{node.net.ip}/32"],
        # leave the kernel's conntrack sizing alone (a namespace may not write it)
        "conntrack": {"maxPerCore": 0, "min": 0},
        "iptables": {"syncPeriod": "10s", "minSyncPeriod": "0s"},
    }


def _write_node_files(node: RealNode, member: Membership) -> Path:
    d = node.dir
    for sub in ("pki", "logs", "containerd", *BIND_PATHS):
        (d / sub).mkdir(parents=True, exist_ok=True)
    pki = d / "pki"
    ca_pki, api_server, ca = member.pki, member.api_server, member.pki / "ca.crt"
    # certificates are issued in the cluster's PKI dir, then moved to the node's
    serving = issue_cert(
        f"{node.name}-serving", f"/CN={node.name}", [f"IP:{node.net.ip}"], pki=ca_pki
    )
    client = issue_cert(
        f"{node.name}-client",
        f"/O=system:nodes/CN=system:node:{node.name}",
        [],
        usage="clientAuth",
        pki=ca_pki,
    )
    for src, dst in ((serving, "kubelet-serving"), (client, "kubelet-client")):
        shutil.move(str(src), pki / f"{dst}.crt")
        shutil.move(str(src.with_suffix(".key")), pki / f"{dst}.key")
    (d / "kubelet.kubeconfig").write_text(
        kubeconfig(api_server, f"system:node:{node.name}", pki / "kubelet-client.crt",
                   pki / "kubelet-client.key", ca=ca)
    )  # fmt: skip
    if member.services:
        (d / "kube-proxy.kubeconfig").write_text(
            kubeconfig(api_server, "system:kube-proxy", ca_pki / "kube-proxy.crt",
                       ca_pki / "kube-proxy.key", ca=ca)
        )  # fmt: skip
        (d / "kube-router.kubeconfig").write_text(
            kubeconfig(api_server, KUBE_ROUTER_USER, ca_pki / "kube-router.crt",
                       ca_pki / "kube-router.key", ca=ca)
        )  # fmt: skip
    (d / "containerd.toml").write_text(_containerd_config(node))
    _write_json(d / "cni-conf" / "10-fogfleet-bed.conflist", _cni_config(node))
    _write_json(d / "kubelet.json", _kubelet_config(node, pki, member))
    _write_json(d / "kube-proxy.json", _kube_proxy_config(node, d / "kube-proxy.kubeconfig"))
    (d / "resolv.conf").write_text("# fogfleet bed: no DNS server (nothing leaves the bed)\n")
    labels = ",".join(f"{k}={v}" for k, v in sorted(node.labels.items()))
    path = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
    cfg = {
        "name": node.name,
        "logs": str(d / "logs"),
        "tmpfs": list(TMPFS_PATHS),
        "binds": [[str(d / sub), target] for sub, target in BIND_PATHS.items()]
        + [[str(d / "resolv.conf"), "/etc/resolv.conf"]],
        "cgroups": {
            "runtime": cgroups.node_path(node.name, "runtime"),
            "agents": cgroups.node_path(node.name, "agents"),
        },
        "containerd_socket": str(node.socket),
        "containerd_ready_file": str(d / "containerd.ready"),
        "processes": {
            "containerd": {
                "argv": ["containerd", "--config", str(d / "containerd.toml"), "--log-level=warn"],
                "path": path,
            },
            "kubelet": {
                "argv": [
                    str(BIN_DIR / "kubelet"),
                    f"--config={d / 'kubelet.json'}",
                    f"--kubeconfig={d / 'kubelet.kubeconfig'}",
                    f"--hostname-override={node.name}",
                    f"--node-ip={node.net.ip}",
                    f"--node-labels={labels}",
                    f"--cert-dir={pki}",
                    "--v=1",
                ],
                "path": path,
            },
            "kube-proxy": {
                "argv": [str(BIN_DIR / "kube-proxy"), f"--config={d / 'kube-proxy.json'}", "--v=1"],
                "path": path,
            },
            # NetworkPolicy, enforced in the node's netns (iptables + ipset on cni0 and eth0):
            # only the firewall; CNI, routes and Services stay the bed's (bednet, kube-proxy).
            "kube-router": {
                "argv": [
                    str(BIN_DIR / "kube-router"),
                    f"--kubeconfig={d / 'kube-router.kubeconfig'}",
                    f"--hostname-override={node.name}",
                    "--run-firewall=true",
                    "--run-router=false",
                    "--run-service-proxy=false",
                    "--run-loadbalancer=false",
                    "--enable-cni=false",
                    "--enable-ipv6=false",
                    f"--service-cluster-ip-range={bednet.SERVICE_CIDR}",
                    "--iptables-sync-period=30s",
                    "--health-port=0",
                    "--metrics-port=0",
                    "--v=1",
                ],
                "path": path,
            },
        },
    }
    if not member.services:
        for name in ("kube-proxy", "kube-router"):
            del cfg["processes"][name]
    return _write_json(d / "nodehost.json", cfg)


# --------------------------------------------------------------------------------------------
# lifecycle


def _ensure_mountpoints() -> None:
    """Create the hard-coded paths the nodes bind over (only once; removed again by down)."""
    created: list[str] = []
    if CREATED_MOUNTPOINTS.exists():
        created = json.loads(CREATED_MOUNTPOINTS.read_text())
    for target in (*TMPFS_PATHS, *BIND_PATHS.values()):
        missing = [p for p in (Path(target), *Path(target).parents) if not p.exists()]
        for p in reversed(missing):
            p.mkdir()
            created.append(str(p))
    if not Path("/etc/resolv.conf").exists():
        Path("/etc/resolv.conf").touch()
        created.append("/etc/resolv.conf")
    _write_json(CREATED_MOUNTPOINTS, sorted(set(created)))


def _remove_mountpoints() -> None:
    if not CREATED_MOUNTPOINTS.exists():
        return
    for target in sorted(json.loads(CREATED_MOUNTPOINTS.read_text()), key=len, reverse=True):
        p = Path(target)
        with contextlib.suppress(OSError):
            p.rmdir() if p.is_dir() else p.unlink()
    CREATED_MOUNTPOINTS.unlink(missing_ok=True)


def _check_host() -> None:
    import os

    missing = [c for c in ("containerd", "runc", "ctr", "iptables", "ipset", "nsenter", "unshare")
               if shutil.which(c) is None]  # fmt: skip
    if not Path(CNI_BIN_DIR, "bridge").exists():
        missing.append(f"{CNI_BIN_DIR}/bridge (containernetworking-plugins)")
    if missing:
        raise HarnessError(
            f"real nodes need {', '.join(missing)}: `make cluster-tools` installs the Debian "
            "packages containerd runc containernetworking-plugins iptables ipset (as root)"
        )
    if os.geteuid() != 0:
        raise HarnessError("real nodes need root (network namespaces, cgroups, containerd)")


def start(nodes: Sequence[RealNode], member: Membership, images: Sequence[Path]) -> None:
    """Start every real node as a member of the cluster ``member`` names, and import the images
    into each."""
    if not nodes:
        return
    _check_host()
    _ensure_mountpoints()
    nets = [n.net for n in nodes]
    for node in nodes:
        t0 = time.monotonic()
        cgroups.create(node.name, node.cpu_millis, node.memory_bytes)
        bednet.add_node(node.net, nets)
        spec = set_link(node)
        _write_node_files(node, member)
        boot(node)
        log(f"{node.name}: containerd up, link {spec.describe()} in {time.monotonic() - t0:.1f}s")
    import_everywhere(nodes, images)


def boot(node: RealNode) -> None:
    """Start the node's nodehost from the files in its directory (a fresh mount namespace:
    empty ``/run/containerd``, the node's own kubelet and containerd roots) and wait until
    its containerd answers. ``start`` boots a new node; nodefaults.reboot boots one again."""
    (node.dir / "containerd.ready").unlink(missing_ok=True)
    argv = [
        "nsenter", f"--net=/run/netns/{node.net.netns}", "--",
        "unshare", "--mount", "--propagation", "private", "--",
        sys.executable, str(HERE / "nodehost.py"), str(node.dir / "nodehost.json"),
    ]  # fmt: skip
    _start(node.process_name, argv)
    deadline = time.monotonic() + 60
    while _node_alive(node) and not (node.dir / "containerd.ready").exists():
        if time.monotonic() > deadline:
            raise HarnessError(f"{node.name}: containerd not up after 60 s\n{diagnose(node)}")
        time.sleep(0.2)


def import_everywhere(nodes: Sequence[RealNode], images: Sequence[Path]) -> None:
    """Preload the images into every node at once, as provisioning would, with the nodes'
    CPU quota lifted meanwhile (unpacking 600 MiB within a 0.4-CPU share takes minutes)."""
    t0 = time.monotonic()

    def preload(node: RealNode) -> None:
        for archive in images:
            import_image(node, archive)

    for node in nodes:
        cgroups.set_cpu_quota(node.name, None)
    try:
        with ThreadPoolExecutor(max_workers=len(nodes)) as pool:
            list(pool.map(preload, nodes))
    finally:
        for node in nodes:
            cgroups.set_cpu_quota(node.name, node.cpu_millis)
    log(f"{len(images)} images in {len(nodes)} nodes in {time.monotonic() - t0:.1f}s")


def _node_alive(node: RealNode) -> bool:
    if _alive(node.process_name) is None:
        raise HarnessError(
            f"{node.name}: nodehost exited; log tail:\n{log_tail(node.process_name)}\n"
            f"containerd:\n{_tail(node.dir / 'logs' / 'containerd.log')}"
        )
    return True


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return f"(no log at {path})"


def diagnose(node: RealNode) -> str:
    """The last lines of every log of a node, for errors and failed tests."""
    parts = [f"--- {node.process_name} ---\n{log_tail(node.process_name)}"]
    for name in ("containerd", "kubelet", "kube-proxy", "kube-router"):
        parts.append(f"--- {node.name}/{name} ---\n{_tail(node.dir / 'logs' / f'{name}.log')}")
    return "\n".join(parts)


def import_image(node: RealNode, archive: Path) -> None:
    run(
        [CTR, f"--address={node.socket}", "-n", "k8s.io", "images", "import",
         "--no-unpack=false", str(archive)],
        timeout=600,
        hint=f"hint: {node.name}'s containerd log: {node.dir / 'logs' / 'containerd.log'}",
    )  # fmt: skip


def images_on(node: RealNode) -> list[str]:
    out = run([CTR, f"--address={node.socket}", "-n", "k8s.io", "images", "ls", "-q"])
    return [line for line in out.split() if line and not line.startswith("sha256:")]


def stop(nodes: Sequence[RealNode]) -> None:
    """Stop the nodes (nodehost cleans its children), then kill anything left in their trees."""
    for node in nodes:
        _stop(node.process_name, grace=30)
        stop_link(node.net.netns)
    cgroups.teardown_all()
    bednet.teardown()
    _remove_mountpoints()
    shutil.rmtree(NODES_DIR, ignore_errors=True)


def stop_one(node: RealNode) -> None:
    """Stop one node and remove what is its alone (processes, link, cgroups, namespace, veth,
    route, directory), leaving the bed's bridge and its other nodes running."""
    _stop(node.process_name, grace=30)
    stop_link(node.net.netns)
    cgroups.kill_all(node.cgroup)
    cgroups.remove(node.cgroup)
    bednet.remove_node(node.net)
    shutil.rmtree(node.dir, ignore_errors=True)


def wait_ready(kubectl: Any, names: Sequence[str], timeout: float = NODE_READY_TIMEOUT) -> None:
    def ready() -> bool:
        proc = kubectl("get", "nodes", "-o", "json", check=False)
        if proc.returncode != 0:
            return False
        ok = set()
        for item in json.loads(proc.stdout)["items"]:
            conds = {c["type"]: c["status"] for c in item.get("status", {}).get("conditions", [])}
            if conds.get("Ready") == "True":
                ok.add(item["metadata"]["name"])
        return set(names) <= ok

    wait_for(f"real nodes {', '.join(names)} Ready", ready, timeout, interval=1)


def run_in_node(
    node: RealNode, *argv: str, timeout: float = 30
) -> subprocess.CompletedProcess[str]:
    """Run a command in the node's network namespace (not its mount namespace)."""
    return subprocess.run(
        ["ip", "netns", "exec", node.net.netns, *argv],
        capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip
