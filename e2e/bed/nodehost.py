#!/usr/bin/env python3
"""The init of one real node: runs inside the node's network and mount namespaces.

    nsenter --net=/run/netns/ffn-<node> unshare --mount --propagation private -- \
        python3 e2e/bed/nodehost.py NODE_DIR/nodehost.json

It makes the node's private view of the paths that containerd and the kubelet hard-code
(``/run/containerd``, ``/var/lib/kubelet``, ``/var/log/pods`` ...; a fresh tmpfs or a bind of
the node's own directory, invisible to the host and gone with the namespace), then starts
containerd in the node's ``runtime`` cgroup and the kubelet, kube-proxy and kube-router (its
NetworkPolicy firewall) in its ``agents`` cgroup, restarts any of them that dies, and on
SIGTERM stops them and kills every process left in the node's cgroups (by pid). The pids of
what runs now (itself included) are kept in ``NODE_DIR/pids.json`` ({name: {"pid",
"starttime"}}), rewritten at every (re)start, so a fault can be injected into exactly that
process (nodefaults.py). Stdlib only.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from e2e.bed import cgroups

_stopping = False


def _say(msg: str) -> None:
    print(f"[nodehost {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def _mount(*args: str) -> None:
    subprocess.run(["mount", *args], check=True)


def _private_paths(cfg: dict[str, Any]) -> None:
    for target in cfg["tmpfs"]:
        Path(target).mkdir(parents=True, exist_ok=True)
        _mount("-t", "tmpfs", "-o", "mode=0755", "tmpfs", target)
    for source, target in cfg["binds"]:
        if Path(source).is_file():
            Path(target).touch(exist_ok=True)
        else:
            Path(source).mkdir(parents=True, exist_ok=True)
            Path(target).mkdir(parents=True, exist_ok=True)
        _mount("--bind", source, target)


def _starttime(pid: int) -> str | None:
    """Field 22 of /proc/PID/stat: with the pid, it names one process for good."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2 :].split()[19]


def _write_pids(path: Path, procs: dict[str, subprocess.Popen[bytes]]) -> None:
    pids = {"nodehost": os.getpid(), **{name: p.pid for name, p in procs.items()}}
    table = {name: {"pid": pid, "starttime": _starttime(pid)} for name, pid in pids.items()}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(table) + "\n")
    tmp.replace(path)  # readers never see half a table


def _spawn(name: str, spec: dict[str, Any], logs: Path, cgroup: str) -> subprocess.Popen[bytes]:
    cgroups.join(os.getpid(), cgroup)  # the child is forked into this cgroup
    out = (logs / f"{name}.log").open("ab")
    env = dict(os.environ, **spec.get("env", {}))
    if "path" in spec:
        env["PATH"] = spec["path"]
    proc = subprocess.Popen(spec["argv"], stdin=subprocess.DEVNULL, stdout=out, stderr=out, env=env)
    _say(f"{name}: started pid {proc.pid}")
    return proc


def _wait_socket(path: str, proc: subprocess.Popen[bytes], timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not Path(path).exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"containerd did not create {path} (exit {proc.poll()})")
        time.sleep(0.1)


def _on_term(signum: int, _frame: object) -> None:
    global _stopping
    _stopping = True


def main(config_path: str) -> int:
    cfg = json.loads(Path(config_path).read_text())
    logs = Path(cfg["logs"])
    logs.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, _on_term)
    _private_paths(cfg)
    if "kube-router" in cfg["processes"]:
        # NetworkPolicy between two pods of this node: their packets cross cni0, a bridge, and
        # iptables sees bridged packets only with this on (per network namespace).
        Path("/proc/sys/net/bridge/bridge-nf-call-iptables").write_text("1\n")
    runtime, agents = cfg["cgroups"]["runtime"], cfg["cgroups"]["agents"]
    order = [("containerd", runtime), ("kubelet", agents)]
    # the cluster's services, where the node runs them (the cloud's real node does not)
    order += [(name, agents) for name in ("kube-proxy", "kube-router") if name in cfg["processes"]]
    procs: dict[str, subprocess.Popen[bytes]] = {}
    restarts: dict[str, float] = {}
    pids_file = Path(config_path).parent / "pids.json"
    for name, cg in order:
        procs[name] = _spawn(name, cfg["processes"][name], logs, cg)
        if name == "containerd":
            _wait_socket(cfg["containerd_socket"], procs[name])
            _say("containerd: socket ready")
            ready = Path(cfg["containerd_ready_file"])
            ready.write_text(str(procs[name].pid))
    cgroups.join(os.getpid(), agents)
    _write_pids(pids_file, procs)
    while not _stopping:
        time.sleep(0.5)
        for name, cg in order:
            code = procs[name].poll()
            if code is None or _stopping:
                continue
            if time.monotonic() - restarts.get(name, 0) < 2:
                continue
            _say(f"{name}: exited with {code}; restarting")
            restarts[name] = time.monotonic()
            procs[name] = _spawn(name, cfg["processes"][name], logs, cg)
            cgroups.join(os.getpid(), agents)
            _write_pids(pids_file, procs)
    _say("stopping")
    pids_file.unlink(missing_ok=True)
    for name in ("kube-router", "kubelet", "kube-proxy", "containerd"):
        if name not in procs:
            continue
        proc = procs[name]
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    killed = cgroups.kill_all(runtime)
    _say(f"stopped; killed {killed} container and shim processes")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
