"""The control plane: etcd, kube-apiserver, kube-controller-manager, kube-scheduler, kwok and
Prometheus as local processes on 127.0.0.1 (CLUSTER.md "Option B": flags, ports, PKI and the
Prometheus config are ours, so nothing listens beyond the bed and nothing downloads binaries).

Prometheus finds the real nodes' pods itself, through the API (kubernetes_sd:
clusterservices.kubernetes_pods_job); the harness writes target files only for the loopback
targets tests add (Cluster.add_prometheus_target).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from e2e.bed.base import (
    BIN_DIR,
    HOST,
    KUBECONFIG,
    PROMETHEUS_TARGETS_DIR,
    STATE_DIR,
    HarnessError,
    free_port,
    load_versions,
    log,
    port_is_free,
    run,
    wait_for,
)
from e2e.bed.bednet import DNS_SERVICE_IP, SERVICE_CIDR
from e2e.bed.cluster import (
    COMPONENTS,
    CONTROLLER_API_BURST,
    CONTROLLER_API_QPS,
    HEARTBEAT_LABEL,
    NODE_LEASE_SECONDS,
    NODE_MONITOR_GRACE_PERIOD,
    NODE_MONITOR_PERIOD,
    POD_EVICTION_TOLERATION_SECONDS,
    PREFERRED_PORTS,
    PROMETHEUS_SCRAPE_INTERVAL,
    _health,
)
from e2e.bed.clusterservices import IN_CLUSTER_PROMETHEUS_URL, kubernetes_pods_job
from e2e.bed.pki import _make_pki, _write_kubeconfig
from e2e.bed.processes import _alive, _proc_starttime, _start, _stop, log_tail

ALLOW_PATHS = "--authorization-always-allow-paths=/healthz,/readyz,/livez,/metrics"

# Prometheus 3 refuses a scrape whose Content-Type it does not know unless told what to
# assume; the bed's small exporters (tests, twins) may answer with none.
FALLBACK_SCRAPE_PROTOCOL = "PrometheusText0.0.4"


def _prometheus_config(ports: Mapping[str, int], real_nodes: Sequence[str] = ()) -> dict[str, Any]:
    pki = STATE_DIR / "pki"
    client_tls = {"cert_file": str(pki / "admin.crt"), "key_file": str(pki / "admin.key")}

    def static(
        job: str, port: int, scheme: str = "http", tls: Mapping[str, Any] | None = None
    ) -> dict[str, Any]:
        cfg: dict[str, Any] = {
            "job_name": job,
            "scheme": scheme,
            "static_configs": [{"targets": [f"{HOST}:{port}"]}],
        }
        if tls is not None:
            cfg["tls_config"] = dict(tls)
        return cfg

    pods = (
        [kubernetes_pods_job(f"https://{HOST}:{ports['kube-apiserver']}", real_nodes, pki)]
        if real_nodes
        else []  # no real node, no pod worth scraping (kwok's pods have no process)
    )  # fmt: skip
    jobs: list[dict[str, Any]] = [
        static("prometheus", ports["prometheus"]),
        static("etcd", ports["etcd"]),
        static(
            "kube-apiserver",
            ports["kube-apiserver"],
            "https",
            {**client_tls, "ca_file": str(pki / "ca.crt")},
        ),
        static(
            "kube-controller-manager",
            ports["kube-controller-manager"],
            "https",
            {**client_tls, "insecure_skip_verify": True},
        ),
        static(
            "kube-scheduler",
            ports["kube-scheduler"],
            "https",
            {**client_tls, "insecure_skip_verify": True},
        ),
        static("kwok", ports["kwok"], "https", {"insecure_skip_verify": True}),
        {
            # Tests (and the metrics twin) add 127.0.0.1 targets by writing a JSON file
            # here: Cluster.add_prometheus_target(). Each file sets its own `job` label.
            "job_name": "file-sd",
            "file_sd_configs": [
                {
                    "files": [str(PROMETHEUS_TARGETS_DIR / "*.json")],
                    "refresh_interval": PROMETHEUS_SCRAPE_INTERVAL,
                }
            ],
        },
        *pods,
    ]
    for job in jobs:
        job["fallback_scrape_protocol"] = FALLBACK_SCRAPE_PROTOCOL
    return {
        "global": {
            "scrape_interval": PROMETHEUS_SCRAPE_INTERVAL,
            "scrape_timeout": PROMETHEUS_SCRAPE_INTERVAL,
            "evaluation_interval": PROMETHEUS_SCRAPE_INTERVAL,
        },
        "scrape_configs": jobs,
    }


@dataclass(frozen=True)
class Heartbeats:
    """How long kwok's fake-node Leases last (kwok renews them every quarter of it) and how
    late a Lease may be before kube-controller-manager marks its node NotReady. The bed's
    defaults are short so the node-failure tests see a failure within seconds."""

    lease_seconds: int = NODE_LEASE_SECONDS
    grace_period: str = NODE_MONITOR_GRACE_PERIOD


def scheduler_argv(kubeconfig: Path, state: Path, port: int) -> list[str]:
    """kube-scheduler of the cluster whose admin ``kubeconfig`` is given, with its config
    (``write_scheduler_config``) and certificates in ``state``."""
    return [
        str(BIN_DIR / "kube-scheduler"),
        f"--config={state / 'scheduler.yaml'}",
        f"--authentication-kubeconfig={kubeconfig}",
        f"--authorization-kubeconfig={kubeconfig}",
        f"--bind-address={HOST}",
        f"--secure-port={port}",
        ALLOW_PATHS,
        f"--cert-dir={state / 'certs' / 'scheduler'}",
    ]


def write_scheduler_config(kubeconfig: Path, state: Path) -> None:
    (state / "scheduler.yaml").write_text(
        json.dumps(
            {
                "apiVersion": "kubescheduler.config.k8s.io/v1",
                "kind": "KubeSchedulerConfiguration",
                "clientConnection": {
                    "kubeconfig": str(kubeconfig),
                    "qps": CONTROLLER_API_QPS,
                    "burst": CONTROLLER_API_BURST,
                },
                "leaderElection": {"leaderElect": False},
            },
            indent=1,
        )
        + "\n"
    )


def kwok_argv(kubeconfig: Path, state: Path, pki: Path, port: int, lease_seconds: int) -> list[str]:
    """kwok playing the kubelet of the cluster's fake nodes (its stages in ``state``/kwok.yaml,
    serving with ``pki``'s admin certificate)."""
    return [
        str(BIN_DIR / "kwok"),
        f"--kubeconfig={kubeconfig}",
        f"--config={state / 'kwok.yaml'}",
        # only the fake nodes: real nodes have kubelets of their own
        "--manage-nodes-with-annotation-selector=kwok.x-k8s.io/node=fake",
        f"--manage-nodes-with-label-selector={HEARTBEAT_LABEL}!=stopped",
        "--node-name=localhost",
        "--node-ip=",
        f"--node-port={port}",
        f"--server-address={HOST}:{port}",
        f"--tls-cert-file={pki / 'admin.crt'}",
        f"--tls-private-key-file={pki / 'admin.key'}",
        f"--node-lease-duration-seconds={lease_seconds}",
        "--cidr=10.0.0.0/16",
        "--v=WARN",  # INFO logs every Lease renewal (about 10 MB an hour)
    ]


def write_kwok_config(state: Path) -> None:
    stages = (BIN_DIR / "kwok-stages.yaml").read_text()
    # Only Stage documents: a KwokConfiguration document here would replace kwok's defaults
    # (v0.8.0 then fails with "node leases parallelism must be greater than 0"); flags suffice.
    (state / "kwok.yaml").write_text(stages)


def _argv(
    ports: Mapping[str, int], heartbeats: Heartbeats | None = None
) -> dict[str, tuple[list[str], dict[str, str] | None]]:
    b, s, pki = BIN_DIR, STATE_DIR, STATE_DIR / "pki"
    heartbeats = heartbeats or Heartbeats()
    kc = str(KUBECONFIG)
    etcd_url = f"http://{HOST}:{ports['etcd']}"
    peer_url = f"http://{HOST}:{ports['etcd-peer']}"
    kwok_env = dict(os.environ, KWOK_WORKDIR=str(s / "kwok"))  # keeps ~/.kwok/kwok.yaml out
    return {
        "etcd": (
            [
                str(b / "etcd"),
                "--name=fogfleet-e2e",
                f"--data-dir={s / 'etcd-data'}",
                f"--listen-client-urls={etcd_url}",
                f"--advertise-client-urls={etcd_url}",
                f"--listen-peer-urls={peer_url}",
                f"--initial-advertise-peer-urls={peer_url}",
                f"--initial-cluster=fogfleet-e2e={peer_url}",
                "--auto-compaction-retention=1",
                "--quota-backend-bytes=8589934592",
                "--unsafe-no-fsync",
                "--log-level=warn",
            ],
            None,
        ),
        "kube-apiserver": (
            [
                str(b / "kube-apiserver"),
                f"--etcd-servers={etcd_url}",
                "--etcd-prefix=/registry",
                f"--bind-address={HOST}",
                f"--secure-port={ports['kube-apiserver']}",
                f"--advertise-address={HOST}",
                "--endpoint-reconciler-type=none",
                f"--tls-cert-file={pki / 'admin.crt'}",
                f"--tls-private-key-file={pki / 'admin.key'}",
                f"--client-ca-file={pki / 'ca.crt'}",
                "--service-account-issuer=https://kubernetes.default.svc.cluster.local",
                f"--service-account-key-file={pki / 'sa.key'}",
                f"--service-account-signing-key-file={pki / 'sa.key'}",
                f"--service-cluster-ip-range={SERVICE_CIDR}",
                "--authorization-mode=Node,RBAC",
                "--allow-privileged=true",
                # real nodes report their bed address; kwok's fake nodes only `localhost`
                "--kubelet-preferred-address-types=InternalIP,Hostname",
                f"--kubelet-client-certificate={pki / 'admin.crt'}",
                f"--kubelet-client-key={pki / 'admin.key'}",
                f"--default-not-ready-toleration-seconds={POD_EVICTION_TOLERATION_SECONDS}",
                f"--default-unreachable-toleration-seconds={POD_EVICTION_TOLERATION_SECONDS}",
                # front-proxy/requestheader settings, so kcm and the scheduler find a complete
                # extension-apiserver-authentication ConfigMap (no aggregated APIs are served)
                f"--requestheader-client-ca-file={pki / 'ca.crt'}",
                "--requestheader-allowed-names=fogfleet-e2e-admin",
                "--requestheader-username-headers=X-Remote-User",
                "--requestheader-group-headers=X-Remote-Group",
                "--requestheader-extra-headers-prefix=X-Remote-Extra-",
                f"--proxy-client-cert-file={pki / 'admin.crt'}",
                f"--proxy-client-key-file={pki / 'admin.key'}",
                f"--cert-dir={s / 'certs'}",
            ],
            None,
        ),
        "kube-controller-manager": (
            [
                str(b / "kube-controller-manager"),
                f"--kubeconfig={kc}",
                f"--authentication-kubeconfig={kc}",
                f"--authorization-kubeconfig={kc}",
                f"--bind-address={HOST}",
                f"--secure-port={ports['kube-controller-manager']}",
                ALLOW_PATHS,
                "--leader-elect=false",
                f"--root-ca-file={pki / 'ca.crt'}",
                f"--service-account-private-key-file={pki / 'sa.key'}",
                f"--cluster-signing-cert-file={pki / 'ca.crt'}",
                f"--cluster-signing-key-file={pki / 'ca.key'}",
                f"--node-monitor-period={NODE_MONITOR_PERIOD}",
                f"--node-monitor-grace-period={heartbeats.grace_period}",
                f"--kube-api-qps={CONTROLLER_API_QPS}",
                f"--kube-api-burst={CONTROLLER_API_BURST}",
                f"--cert-dir={s / 'certs' / 'kcm'}",
            ],
            None,
        ),
        "kube-scheduler": (
            scheduler_argv(KUBECONFIG, s, ports["kube-scheduler"]),
            None,
        ),
        "kwok": (
            kwok_argv(KUBECONFIG, s, pki, ports["kwok"], heartbeats.lease_seconds),
            kwok_env,
        ),
        "prometheus": (
            [
                str(b / "prometheus"),
                f"--config.file={s / 'prometheus.yml'}",
                f"--storage.tsdb.path={s / 'prometheus-data'}",
                f"--web.listen-address={HOST}:{ports['prometheus']}",
                "--web.enable-lifecycle",
                "--storage.tsdb.retention.time=1d",
                "--log.level=warn",
            ],
            None,
        ),
    }


def _choose_ports() -> dict[str, int]:
    ports: dict[str, int] = {}
    for name, preferred in PREFERRED_PORTS.items():
        port = preferred if port_is_free(preferred) else free_port()
        while port in ports.values():
            port = free_port()
        ports[name] = port
    return ports


def _write_configs(ports: Mapping[str, int], real_nodes: Sequence[str] = ()) -> None:
    for d in ("logs", "pids", "certs", "kwok", "prometheus-data"):
        (STATE_DIR / d).mkdir(parents=True, exist_ok=True)
    PROMETHEUS_TARGETS_DIR.mkdir(parents=True, exist_ok=True)
    _make_pki()
    _write_kubeconfig(f"https://{HOST}:{ports['kube-apiserver']}")
    write_scheduler_config(KUBECONFIG, STATE_DIR)
    write_kwok_config(STATE_DIR)
    (STATE_DIR / "prometheus.yml").write_text(
        json.dumps(_prometheus_config(ports, real_nodes), indent=1)
    )
    run([BIN_DIR / "promtool", "check", "config", STATE_DIR / "prometheus.yml"])


def _write_state(
    ports: Mapping[str, int],
    phase: str,
    real_nodes: list[str] | None = None,
    profile: str = "default",
) -> None:
    state = {
        "phase": phase,
        "profile": profile,
        "real_nodes": list(real_nodes or []),
        "ports": dict(ports),
        "versions": load_versions(),
        "api_server": f"https://{HOST}:{ports['kube-apiserver']}",
        "kubeconfig": str(KUBECONFIG),
        "prometheus_url": f"http://{HOST}:{ports['prometheus']}",
        "prometheus_targets_dir": str(PROMETHEUS_TARGETS_DIR),
        # what pods use (clusterservices.py); only real nodes run pods that could
        "in_cluster_prometheus_url": IN_CLUSTER_PROMETHEUS_URL if real_nodes else "",
        "cluster_dns": DNS_SERVICE_IP if real_nodes else "",
        "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    tmp = STATE_DIR / ".state.json.tmp"
    tmp.write_text(json.dumps(state, indent=1) + "\n")
    tmp.replace(STATE_DIR / "state.json")


_START_TIMEOUTS = {
    "etcd": 30,
    "kube-apiserver": 180,
    "kube-controller-manager": 90,
    "kube-scheduler": 90,
    "kwok": 60,
    "prometheus": 60,
}


def _wait_healthy(
    name: str,
    ports: Mapping[str, int],
    health: Callable[[str, Mapping[str, int]], tuple[bool, str]] = _health,
    timeout: float | None = None,
) -> None:
    """Wait until process ``name`` is healthy by ``health`` (the site's ``_health``, or the
    cloud's), at most ``timeout`` (the site's start-up timeouts by default); one that exits
    fails at once, with its log's tail."""
    limit = _START_TIMEOUTS[name] if timeout is None else timeout

    def check() -> bool:
        if _alive(name) is None:
            raise HarnessError(f"{name} exited during start-up; log tail:\n{log_tail(name)}")
        return health(name, ports)[0]

    deadline = time.monotonic() + limit
    t0 = time.monotonic()
    while not check():
        if time.monotonic() > deadline:
            raise HarnessError(
                f"{name} not healthy after {limit:g}s "
                f"({health(name, ports)[1]}); log tail:\n{log_tail(name)}"
            )
        time.sleep(0.3)
    log(f"{name}: healthy after {time.monotonic() - t0:.1f}s")


def _stop_all() -> None:
    for name in reversed(COMPONENTS):
        _stop(name)


# what a control-plane restart stops, in stop order (started again in reverse)
API_AND_STORE = ("kube-apiserver", "etcd")


@dataclass(frozen=True)
class Restart:
    """A control-plane restart as it happened: when the API went away and came back."""

    components: tuple[str, ...]
    old_pids: dict[str, int]
    new_pids: dict[str, int]
    stopped_seconds: float  # from the first stop signal until every process had exited
    down_seconds: float  # from the first stop signal until the API server was ready again


def restart_components(
    ports: Mapping[str, int],
    components: tuple[str, ...] = API_AND_STORE,
    *,
    kill: bool = False,
    pause_seconds: float = 0.0,
) -> Restart:
    """Stop ``components`` by pid (in the order given: SIGTERM, or SIGKILL with ``kill``), wait
    ``pause_seconds``, start them again in reverse order with their argv, ports and data
    directories of start-up, each healthy before the next starts.

    Everything else keeps running and has to reconnect: kube-controller-manager, the
    scheduler, kwok, the real nodes' kubelets and kube-proxies, the operator, the gateway.
    """
    unknown = [c for c in components if c not in COMPONENTS]
    if unknown:
        raise HarnessError(f"unknown components {unknown}: {COMPONENTS}")
    argv = _argv(ports)
    old: dict[str, int] = {}
    for name in components:
        pid = _alive(name)
        if pid is None:
            raise HarnessError(f"{name} is not running: nothing to restart")
        old[name] = pid
    t0 = time.monotonic()
    for name in components:
        pid, starttime = old[name], _proc_starttime(old[name])
        _stop(name, grace=0 if kill else 10)
        gone = partial(lambda p, t: _proc_starttime(p) != t, pid, starttime)
        wait_for(f"{name} pid {pid} gone", gone, 10, 0.05)
    stopped = time.monotonic() - t0
    time.sleep(pause_seconds)
    new: dict[str, int] = {}
    for name in reversed(components):
        new[name] = _start(name, *argv[name])
        _wait_healthy(name, ports)
    down = time.monotonic() - t0
    log(f"restarted {', '.join(components)}: stopped in {stopped:.1f}s, down {down:.1f}s")
    return Restart(components, old, new, stopped, down)
