"""The bed: the control plane, kwok's fake nodes and the real nodes, started and stopped as one.

ensure_up()  idempotent: reuses a healthy bed, else restarts it from nothing
down()       stops every process by pid and removes every file, mount, link and cgroup
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Mapping
from functools import partial
from pathlib import Path

from e2e.bed import bednet, cgroups, cloud, clusterservices, heartbeats, ocm, realnodes
from e2e.bed.base import (
    BIN_DIR,
    HERE,
    HOST,
    STATE_DIR,
    VERSIONS_FILE,
    HarnessError,
    answers,
    http_get,
    load_versions,
    locked,
    log,
    wait_for,
)
from e2e.bed.cluster import COMPONENTS, Cluster, _health, _read_state, running
from e2e.bed.controlplane import (
    _argv,
    _choose_ports,
    _stop_all,
    _wait_healthy,
    _write_configs,
    _write_state,
)
from e2e.bed.fakenodes import NODES_FILE, _apply_nodes
from e2e.bed.processes import _alive, _start, _stop, log_tail
from e2e.bed.tools import ensure_built

GATEWAY = "bed-gateway"
COREDNS = clusterservices.COREDNS
# Processes of beds started by older versions of the harness, stopped by `down` all the same.
RETIRED = ("pod-discovery",)


def _bed_images() -> list[Path]:
    """Image archives every real node gets (the pause image first)."""
    from e2e.bed import images

    return images.bed_archives()


def _kubernetes_endpoints(cluster: Cluster) -> None:
    """Point the `kubernetes` Service at the apiserver's bridge address (no reconciler runs)."""
    port = cluster.ports["kube-apiserver"]
    slice_ = {
        "apiVersion": "discovery.k8s.io/v1",
        "kind": "EndpointSlice",
        "metadata": {
            "name": "kubernetes-bed",
            "namespace": "default",
            "labels": {
                "kubernetes.io/service-name": "kubernetes",
                "endpointslice.kubernetes.io/managed-by": "fogfleet-e2e-harness",
            },
        },
        "addressType": "IPv4",
        "endpoints": [{"addresses": [bednet.BRIDGE_IP], "conditions": {"ready": True}}],
        "ports": [{"name": "https", "port": port, "protocol": "TCP"}],
    }
    cluster.kubectl("apply", "-f", "-", input=json.dumps(slice_))


def _start_real_nodes(cluster: Cluster, real: list[realnodes.RealNode]) -> None:
    """The bridge, the gateway (the apiserver and Prometheus at the bridge address), cluster
    DNS, the Services pods reach them by, then the nodes."""
    t0 = time.monotonic()
    images = _bed_images()
    bednet.ensure_bridge()
    relayed = [cluster.ports["kube-apiserver"], cluster.ports["prometheus"]]
    _start(
        GATEWAY,
        [sys.executable, str(HERE / "gateway.py"),
         *(f"{bednet.BRIDGE_IP}:{p}={HOST}:{p}" for p in relayed)],
    )  # fmt: skip
    for port in relayed:
        wait_for(
            f"the bed gateway on {bednet.BRIDGE_IP}:{port}",
            partial(answers, bednet.BRIDGE_IP, port),
            20,
        )
    _kubernetes_endpoints(cluster)
    cluster.kubectl(
        "apply", "-f", "-",
        input=json.dumps({"apiVersion": "v1", "kind": "List", "items": realnodes.KUBE_ROUTER_RBAC}),
    )  # fmt: skip
    cluster.kubectl(
        "apply", "-f", "-",
        input=clusterservices.dump(clusterservices.service_objects(cluster.ports["prometheus"])),
    )  # fmt: skip
    _start(COREDNS, clusterservices.coredns_argv(BIN_DIR, cluster.ports, cluster.api_server))
    try:
        wait_for("CoreDNS ready (its Services, EndpointSlices and Namespaces synced)",
                 partial(coredns_ready, cluster.ports), 60)  # fmt: skip
    except HarnessError as exc:
        raise HarnessError(f"{exc}; CoreDNS's log tail:\n{log_tail(COREDNS)}") from exc
    api_server = f"https://{bednet.BRIDGE_IP}:{cluster.ports['kube-apiserver']}"
    realnodes.start(real, realnodes.Membership(api_server), images)
    IMPORTED.write_text(json.dumps(sorted(a.name for a in images)) + "\n")
    log(f"real nodes started in {time.monotonic() - t0:.1f}s")


def coredns_ready(ports: Mapping[str, int]) -> bool:
    """CoreDNS runs, and its ready plugin answers 200 (once the kubernetes plugin synced)."""
    if _alive(COREDNS) is None:
        return False
    try:
        return http_get(f"http://{HOST}:{ports['coredns-ready']}/ready").strip() == "OK"
    except OSError:
        return False


IMPORTED = STATE_DIR / "imported-images.json"


def _refresh_images(cluster: Cluster) -> None:
    """Rebuild what the repository changed since the bed started and import it into the
    running real nodes (so `make e2e` on a running bed tests the current code)."""
    if not cluster.real_nodes:
        return
    archives = _bed_images()
    known = set(json.loads(IMPORTED.read_text())) if IMPORTED.exists() else set()
    fresh = [a for a in archives if a.name not in known]
    if fresh:
        nodes = [realnodes.declared(n) for n in cluster.real_nodes]
        realnodes.import_everywhere(nodes, fresh)
    IMPORTED.write_text(json.dumps(sorted(a.name for a in archives)) + "\n")


def _stop_everything() -> None:
    ocm.stop()
    cloud.stop()
    state = _read_state() or {}
    names = state.get("real_nodes", [])
    nodes = [realnodes.RealNode(n, i + 1, {}, 0, 0) for i, n in enumerate(names)]
    realnodes.stop(nodes)
    for name in (COREDNS, GATEWAY, *RETIRED):
        _stop(name)
    _stop_all()


def ensure_up(*, nodes: bool = True, profile: str = realnodes.DEFAULT_PROFILE) -> Cluster:
    """Start the bed unless it already runs healthy with ``profile``; return it.

    The bed is the control plane, the real nodes of the profile (``realnodes.PROFILES``;
    ``default``: those of e2e/bed/nodes.yaml) and, with `nodes`, the fake nodes of
    nodes.yaml. A bed that was already running with the same profile is left alone (a scale
    test may have replaced the fake node set); one with another profile is restarted.
    """
    real = realnodes.profile_nodes(profile)  # an unknown profile fails before anything stops
    with locked():
        cluster = running()
        state = _read_state() or {}
        same = state.get("versions") == load_versions()
        if cluster is not None and same and cluster.profile == profile:
            log(f"already running and healthy ({profile} bed): {cluster.api_server}")
            heartbeats.restore()  # a scale run that died may have left slow ones
            _refresh_images(cluster)
            return cluster
        if cluster is not None and not same:
            log(f"running with other versions than {VERSIONS_FILE.name}; restarting it")
        elif cluster is not None:
            log(f"running the {cluster.profile} bed; restarting it as the {profile} bed")
        elif _read_state() is not None or any(_alive(c) for c in COMPONENTS):
            sick = [c for c in COMPONENTS if _alive(c) is None]
            log(f"found a stale or unhealthy cluster (down: {sick or 'none'}); restarting it")
        _stop_everything()
        bednet.teardown()
        shutil.rmtree(STATE_DIR, ignore_errors=True)
        ensure_built()
        fake, _ = realnodes.split_manifest(NODES_FILE.read_text())
        t0 = time.monotonic()
        STATE_DIR.mkdir(parents=True)
        ports = _choose_ports()
        _write_state(ports, "starting", [n.name for n in real], profile)
        _write_configs(ports, [n.name for n in real])
        argv = _argv(ports)
        cluster = Cluster.from_state({"ports": ports})
        try:
            for group in (
                ("etcd",),
                ("kube-apiserver",),
                ("kube-controller-manager", "kube-scheduler"),
                ("kwok",),
                ("prometheus",),
            ):
                if group == ("prometheus",):  # it reads pods as itself from its first second
                    cluster.kubectl("apply", "-f", "-",
                                    input=clusterservices.dump(clusterservices.RBAC))  # fmt: skip
                for name in group:
                    _start(name, *argv[name])
                for name in group:
                    _wait_healthy(name, ports)
            wait_for(
                "the default ServiceAccount",
                lambda: cluster.kubectl("get", "sa", "default", check=False).returncode == 0,
                60,
            )
            if real:
                _start_real_nodes(cluster, real)
            if nodes:
                _apply_nodes(
                    cluster, json.dumps({"apiVersion": "v1", "kind": "List", "items": fake})
                )
            if real:
                realnodes.wait_ready(cluster.kubectl, [n.name for n in real])
        except BaseException:
            log(f"start-up failed; stopping what was started (logs kept in {STATE_DIR / 'logs'})")
            for node in real:
                if node.dir.exists():
                    log(realnodes.diagnose(node))
            _stop_everything()
            _write_state(ports, "failed", [n.name for n in real], profile)
            raise
        _write_state(ports, "running", [n.name for n in real], profile)
        log(f"cluster up in {time.monotonic() - t0:.1f}s ({profile} bed, {len(real)} real nodes)")
        return Cluster.from_state(_read_state() or {})  # with its real nodes and versions


def ensure_cloud(
    site: Cluster, *, real_node: bool = False
) -> tuple[cloud.CloudCluster, ocm.Joined]:
    """The cloud cluster beside the running bed ``site``, joined to it by OCM (``cloud``,
    ``ocm``), with its real node (``cloud.start_node``) when ``real_node`` and the site runs
    real nodes; a cloud that already runs joined is left alone."""
    from e2e.bed import images

    with locked():
        ensure_built(["ocm"])
        c = cloud.start(f"http://{HOST}:{site.ports['etcd']}")
        joined = ocm.join(c, site.kubeconfig, load_versions()["OCM_VERSION"])
        if real_node and site.real_nodes:
            cloud.start_node(c, images.cloud_archives())
        return c, joined


def leftovers() -> list[str]:
    """What a stopped bed must not leave behind: processes, namespaces, links, cgroups, paths."""
    found: list[str] = []
    if STATE_DIR.exists():
        found.append(f"state directory {STATE_DIR}")
    pids = cgroups.pids(f"/{cgroups.TOP}")
    if pids:
        found.append(f"processes in /{cgroups.TOP} cgroups: {sorted(pids)[:10]}")
    for h in cgroups.every_hierarchy():
        if (h / cgroups.TOP).exists():
            found.append(f"cgroup {h / cgroups.TOP}")
    netns = Path("/run/netns")
    found += (
        [f"netns {p.name}" for p in netns.glob(f"{bednet.NETNS_PREFIX}*")] if netns.exists() else []
    )
    found += [f"link {p.name}" for p in Path("/sys/class/net").glob("ff*")]
    watched = (str(STATE_DIR), *realnodes.TMPFS_PATHS, *realnodes.BIND_PATHS.values())
    for line in Path("/proc/self/mounts").read_text().splitlines():
        target = line.split()[1]
        if any(target == w or target.startswith(w + "/") for w in watched):
            found.append(f"mount {target}")
    return found


def down() -> int:
    """Stop every process the harness started (stored pids only) and remove the state.

    Real nodes: their processes (by pid, then whatever is left in their cgroups), namespaces,
    veths, bridge, routes, cgroups, the mount points the bed created and their directories.
    Returns 1 (and says what) when anything is left behind.
    """
    with locked():
        if STATE_DIR.exists():
            _stop_everything()
            shutil.rmtree(STATE_DIR, ignore_errors=True)
            log(f"removed {STATE_DIR}")
        else:
            log("not running (no state)")
            bednet.teardown()
            cgroups.teardown_all()
        left = leftovers()
        for item in left:
            log(f"left behind: {item}")
        return 1 if left else 0


def status() -> int:
    state = _read_state()
    if state is None:
        print("fogfleet e2e cluster: not created (run `harness.py up`)")
        return 1
    cluster = Cluster.from_state(state)
    print(
        f"fogfleet e2e cluster: {state.get('phase')}, {cluster.profile} bed  (state: {STATE_DIR})"
    )
    print(f"{'component':<25} {'pid':>8} {'port':>6}  health")
    all_ok = True
    for name in COMPONENTS:
        pid = _alive(name)
        ok, detail = _health(name, cluster.ports)
        all_ok &= ok and pid is not None
        print(
            f"{name:<25} {pid or '-':>8} {cluster.ports[name]:>6}  "
            f"{'ok' if ok else 'DOWN'} {'' if ok else detail[:60]}"
        )
    real = state.get("real_nodes", [])
    for name in real:
        node = realnodes.declared(name)
        pid = _alive(node.process_name)
        all_ok &= pid is not None
        link = node.link
        print(
            f"{'node ' + name:<25} {pid or '-':>8} {'':>6}  {'ok' if pid else 'DOWN'}  "
            f"cpu {node.cpu_millis}m, memory {node.memory_bytes // 2**20}Mi, {node.net.ip}, "
            f"pods {node.net.pod_cidr}, link {link.get('type')} "
            f"{link.get('latencyMillis')}±{link.get('jitterMillis', 0)} ms "
            f"{link.get('bandwidthMbps')} Mbit/s"
        )
    print(f"kubeconfig:      {cluster.kubeconfig}")
    print(f"api server:      {cluster.api_server}")
    print(f"prometheus:      {cluster.prometheus_url}")
    if cluster.real_nodes:
        ok = coredns_ready(cluster.ports)
        all_ok &= ok
        print(f"  in cluster:    {cluster.in_cluster_prometheus_url} (monitoring/prometheus)")
        print(f"cluster dns:     {cluster.dns_service_ip} (Service kube-system/kube-dns, "
              f"CoreDNS on {bednet.BRIDGE_IP}:53: {'ok' if ok else 'DOWN'})")  # fmt: skip
    print(f"scrape targets:  pods through kubernetes_sd; tests' loopback targets in "
          f"{cluster.prometheus_targets_dir}/*.json")  # fmt: skip
    hub = cloud.running()
    if hub is not None or any(_alive(n) for n in (*cloud.COMPONENTS, *ocm.PROCESSES)):
        alive = {n: _alive(n) for n in (*cloud.COMPONENTS, *ocm.PROCESSES)}
        all_ok &= hub is not None and all(alive.values())
        print(f"cloud cluster:   {hub.api_server if hub else 'DOWN'} (OCM hub; kubeconfig "
              f"{cloud.KUBECONFIG})")  # fmt: skip
        print("  processes:     " + ", ".join(f"{n} {p or 'DOWN'}" for n, p in alive.items()))
    print(f"logs:            {cluster.logs_dir}/<component>.log")
    if all_ok:
        nodes = cluster.kubectl("get", "nodes", "--no-headers", check=False).stdout
        print(f"nodes:           {len(nodes.splitlines())}")
    return 0 if all_ok else 1
