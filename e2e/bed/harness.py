#!/usr/bin/env python3
"""A real Kubernetes control plane for fogfleet's e2e tests, run as local processes (no Docker).

    python e2e/bed/harness.py build [--only T,..] | down | status
    python e2e/bed/harness.py up [--profile default|paper|kwok] [--cloud]
    python e2e/bed/harness.py nodes [--robots N --edges M --cloud K]
    python e2e/bed/harness.py kubectl ARGS... | helm ARGS...
    python e2e/bed/harness.py fault NODE restart kubelet|containerd|kube-proxy | reboot

Why it looks like this (see e2e/README.md and /work/shared/design/CLUSTER.md):

* Every binary is built from published Go modules (k8s.io/kubernetes through a wrapper module
  whose ``replace`` lines are generated from k8s's own go.mod, kwok, etcd, helm, kube-router,
  Prometheus with only kubernetes_sd, CoreDNS with only the bed's plugins); only the real
  nodes' runtime (containerd, runc, CNI plugins) comes from Debian packages. Versions live in
  ``versions.env`` next to this file; builds are cached under
  ``${XDG_CACHE_HOME:-~/.cache}/fogfleet/tools/<tool>-<version>/`` and reused after a
  ``--version`` check. ``GOTOOLCHAIN=local`` always: a too-old Go fails at once.
* The processes are started by this module directly (CLUSTER.md "Option B"), not by kwokctl:
  flags, ports, PKI and the Prometheus config are all ours, so nothing listens beyond
  127.0.0.1 and nothing tries to download release binaries.
* kwok plays every kubelet. Fake nodes report ``localhost`` as their only address, so the
  apiserver's kubelet calls reach kwok on loopback. Pod and Service IPs are data only.
* Processes are detached (own session) and outlive this script; pids and start times are
  stored, and ``down`` signals exactly those pids after checking they are still ours.

Only the standard library is used, so the script runs with any python3 >= 3.11.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Mapping
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from e2e.bed import links, realnodes
from e2e.bed.base import (
    BIN_DIR,
    CACHE_ROOT,
    KUBECONFIG,
    PROMETHEUS_TARGETS_DIR,
    STATE_DIR,
    TOOLS_DIR,
    HarnessError,
    load_versions,
    locked,
    log,
    run,
)
from e2e.bed.bed import down, ensure_cloud, ensure_up, status
from e2e.bed.cloud import NODE
from e2e.bed.cluster import COMPONENTS, Cluster, running
from e2e.bed.fakenodes import NODES_FILE, create_nodes, generated_nodes, node_object
from e2e.bed.gomodule import GoToolchain
from e2e.bed.realnodes import DEFAULT_PROFILE, PROFILES
from e2e.bed.tools import CLOUD_TOOLS, TOOLS, ensure_built

__all__ = [
    "BIN_DIR",
    "CACHE_ROOT",
    "COMPONENTS",
    "KUBECONFIG",
    "NODES_FILE",
    "PROMETHEUS_TARGETS_DIR",
    "STATE_DIR",
    "TOOLS_DIR",
    "Cluster",
    "GoToolchain",
    "HarnessError",
    "create_nodes",
    "down",
    "ensure_built",
    "ensure_up",
    "generated_nodes",
    "load_versions",
    "locked",
    "log",
    "node_object",
    "run",
    "running",
]


def _exec(argv: list[str], env: Mapping[str, str] | None = None) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(argv[0], argv, dict(env if env is not None else os.environ))


def _link(argv: list[str]) -> int:
    """``harness.py link NODE [--delay ...] [--reset]``: change a running real node's link
    (here, above both: ``realnodes`` knows the node and applies ``links``' settings)."""
    ns = links.parse_args(argv)
    node = realnodes.declared(ns.node)
    spec = realnodes.set_link(node, **({} if ns.reset else links.change_from_args(ns)))
    print(f"{ns.node}: {spec.describe()}")
    return 0


def _fault(argv: list[str]) -> int:
    """``harness.py fault NODE restart COMPONENT | reboot [--down S]``: a real node's own
    processes fail (nodefaults.py)."""
    from e2e.bed import nodefaults

    parser = argparse.ArgumentParser(prog="harness.py fault")
    parser.add_argument("node")
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("restart", help="SIGTERM one component by pid; its nodehost restarts it")
    r.add_argument("component", choices=nodefaults.COMPONENTS)
    b = sub.add_parser("reboot", help="SIGKILL everything in the node's cgroups, boot it again")
    b.add_argument("--down", type=float, default=0.0, help="seconds to stay down")
    ns = parser.parse_args(argv)
    node = realnodes.declared(ns.node)
    if ns.what == "restart":
        print(nodefaults.restart(node, ns.component))
    else:
        print(nodefaults.reboot(node, ns.down))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    # passthroughs first: their arguments are not ours to parse
    if args and args[0] == "kubectl":
        with locked():
            ensure_built(["k8s"], quiet=True)
        if not KUBECONFIG.exists():
            raise HarnessError("no cluster: run `harness.py up` first")
        _exec([str(BIN_DIR / "kubectl"), f"--kubeconfig={KUBECONFIG}", *args[1:]])
    if args and args[0] == "link":
        return _link(args[1:])
    if args and args[0] == "fault":
        return _fault(args[1:])
    if args and args[0] == "helm":
        with locked():
            ensure_built(["helm"], quiet=True)
        home = CACHE_ROOT / "helm-home"
        env = dict(
            os.environ,
            HELM_CACHE_HOME=str(home / "cache"),
            HELM_CONFIG_HOME=str(home / "config"),
            HELM_DATA_HOME=str(home / "data"),
        )
        if KUBECONFIG.exists():
            env["KUBECONFIG"] = str(KUBECONFIG)
        _exec([str(BIN_DIR / "helm"), *args[1:]], env)

    parser = argparse.ArgumentParser(prog="harness.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="build or reuse the pinned tools")
    b.add_argument(
        "--only",
        default=",".join(TOOLS),
        help=f"comma list of {','.join(TOOLS)} (default), {','.join(CLOUD_TOOLS)} (the cloud's)",
    )
    b.add_argument("--force", action="store_true", help="rebuild even when cached")
    u = sub.add_parser("up", help="start the control plane (idempotent)")
    u.add_argument(
        "--profile",
        default=DEFAULT_PROFILE,
        choices=sorted(PROFILES),
        help="which real nodes the bed runs (a running bed of another profile is restarted)",
    )
    u.add_argument(
        "--cloud",
        action="store_true",
        help="also a cloud cluster beside it, joined by Open Cluster Management (e2e/bed/ocm.py)",
    )
    sub.add_parser("down", help="stop the control plane and remove its state")
    sub.add_parser("status", help="components, pids, ports, health")
    n = sub.add_parser("nodes", help="replace the fake nodes (default: nodes.yaml)")
    n.add_argument("--robots", type=int)
    n.add_argument("--edges", type=int)
    n.add_argument("--cloud", type=int, default=1)
    sub.add_parser("kubectl", help="kubectl ARGS... with the test kubeconfig")
    sub.add_parser("helm", help="helm ARGS... (cached helm binary)")
    sub.add_parser(
        "link", help="NODE [--delay 20ms] [--jitter 5ms] [--rate 50mbit] [--loss 100%%] [--reset]"
    )
    sub.add_parser("fault", help="NODE restart kubelet|containerd|kube-proxy | NODE reboot")
    ns = parser.parse_args(args)

    if ns.cmd == "build":
        with locked():
            t0 = time.monotonic()
            bin_dir = ensure_built([t for t in ns.only.split(",") if t], force=ns.force)
        log(f"tools ready in {bin_dir} ({time.monotonic() - t0:.1f}s)")
        return 0
    if ns.cmd == "up":
        cluster = ensure_up(profile=ns.profile)
        print(f"bed profile: {cluster.profile} ({', '.join(cluster.real_nodes)})")
        print(f"kubeconfig: {cluster.kubeconfig}")
        print(f"api server: {cluster.api_server}")
        print(f"prometheus: {cluster.prometheus_url}")
        if cluster.real_nodes:
            print(f"prometheus in cluster: {cluster.in_cluster_prometheus_url}")
            print(f"cluster dns: {cluster.dns_service_ip}")
        if ns.cloud:
            cloud, joined = ensure_cloud(cluster, real_node=True)
            print(f"cloud api server: {cloud.api_server} (OCM hub)")
            if cluster.real_nodes:
                print(f"cloud real node: {NODE.name} (router {cloud.cloud_router_for_pods})")
            print(f"cloud kubeconfig: {cloud.kubeconfig}")
            print(f"managed clusters: {', '.join(joined.clusters)} (Available)")
        print(f"export KUBECONFIG={cluster.kubeconfig}")
        return 0
    if ns.cmd == "down":
        return down()
    if ns.cmd == "status":
        return status()
    if ns.cmd == "nodes":
        names = create_nodes(ns.robots, ns.edges, ns.cloud)
        print(f"{len(names)} nodes: {' '.join(names)}")
        return 0
    parser.error(f"unknown command {ns.cmd}")
    return 2


if __name__ == "__main__":
    try:
        sys.exit(main())
    except HarnessError as exc:
        print(f"harness: error: {exc}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        sys.exit(130)
