"""The bed: the control plane, kwok's fake nodes and the real nodes, started and stopped as one.

ensure_up()  idempotent: reuses a healthy bed, else restarts it from nothing
down()       stops every process by pid and removes every file, mount, link and cgroup
"""

from __future__ import annotations

import shutil
import time

from e2e.cluster.base import (
    STATE_DIR,
    VERSIONS_FILE,
    load_versions,
    locked,
    log,
    wait_for,
)
from e2e.cluster.cluster import COMPONENTS, Cluster, _health, _read_state, running
from e2e.cluster.controlplane import (
    _argv,
    _choose_ports,
    _stop_all,
    _wait_healthy,
    _write_configs,
    _write_state,
)
from e2e.cluster.fakenodes import NODES_FILE, _apply_nodes
from e2e.cluster.processes import _alive, _start
from e2e.cluster.tools import ensure_built


def ensure_up(*, nodes: bool = True) -> Cluster:
    """Start the control plane unless it already runs healthy; return it.

    With `nodes`, a fresh cluster gets the fake Nodes of e2e/cluster/nodes.yaml. A cluster that
    was already running is left alone (a scale test may have replaced the node set).
    """
    with locked():
        cluster = running()
        state = _read_state() or {}
        if cluster is not None and state.get("versions") == load_versions():
            log(f"already running and healthy: {cluster.api_server}")
            return cluster
        if cluster is not None:
            log(f"running with other versions than {VERSIONS_FILE.name}; restarting it")
        if _read_state() is not None or any(_alive(c) for c in COMPONENTS):
            sick = [c for c in COMPONENTS if _alive(c) is None]
            log(f"found a stale or unhealthy cluster (down: {sick or 'none'}); restarting it")
            _stop_all()
        shutil.rmtree(STATE_DIR, ignore_errors=True)
        ensure_built()
        t0 = time.monotonic()
        STATE_DIR.mkdir(parents=True)
        ports = _choose_ports()
        _write_state(ports, "starting")
        _write_configs(ports)
        argv = _argv(ports)
        try:
            for group in (
                ("etcd",),
                ("kube-apiserver",),
                ("kube-controller-manager", "kube-scheduler"),
                ("kwok",),
                ("prometheus",),
            ):
                for name in group:
                    _start(name, *argv[name])
                for name in group:
                    _wait_healthy(name, ports)
            cluster = Cluster.from_state({"ports": ports})
            wait_for(
                "the default ServiceAccount",
                lambda: cluster.kubectl("get", "sa", "default", check=False).returncode == 0,
                60,
            )
            if nodes:
                _apply_nodes(cluster, NODES_FILE.read_text())
        except BaseException:
            log(f"start-up failed; stopping what was started (logs kept in {STATE_DIR / 'logs'})")
            _stop_all()
            _write_state(ports, "failed")
            raise
        _write_state(ports, "running")
        log(f"cluster up in {time.monotonic() - t0:.1f}s")
        return cluster


def down() -> None:
    """Stop every process the harness started (stored pids only) and remove the state."""
    with locked():
        if not STATE_DIR.exists():
            log("not running (no state)")
            return
        _stop_all()
        shutil.rmtree(STATE_DIR, ignore_errors=True)
        log(f"removed {STATE_DIR}")


def status() -> int:
    state = _read_state()
    if state is None:
        print("fogfleet e2e cluster: not created (run `harness.py up`)")
        return 1
    cluster = Cluster.from_state(state)
    print(f"fogfleet e2e cluster: {state.get('phase')}  (state: {STATE_DIR})")
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
    print(f"kubeconfig:      {cluster.kubeconfig}")
    print(f"api server:      {cluster.api_server}")
    print(f"prometheus:      {cluster.prometheus_url}")
    print(f"scrape targets:  {cluster.prometheus_targets_dir}/*.json")
    print(f"logs:            {cluster.logs_dir}/<component>.log")
    if all_ok:
        nodes = cluster.kubectl("get", "nodes", "--no-headers", check=False).stdout
        print(f"nodes:           {len(nodes.splitlines())}")
    return 0 if all_ok else 1
