"""cgroup v1 trees that size and contain a real node.

Each real node gets ``/fogfleet/<node>`` in every mounted hierarchy, with a CPU weight in
proportion to its size and a memory limit; ``/fogfleet`` itself outweighs the control plane
(``TOP_CPU_SHARES``). Below a node: ``pods`` is the kubelet's cgroup root (its QoS tree
``kubepods/...`` and every container) and carries the node's CFS quota (its CPU share of this
machine), ``runtime`` holds containerd and its shims, ``agents`` the kubelet, kube-proxy and
kube-router.

The node's agents and runtime run beside its quota, not inside it, and behind its pods
(``AGENT_SHARES``). The bed shrinks a robot's
computer (6 cores of a NUC) by F = 15 to 400m, but not the kubelet: its housekeeping, probes
and status updates still come in bursts of tens of milliseconds of CPU, which on the real
computer take one of its cores for a moment and here took the whole robot. Measured on
warehouse-lite (2026-11-28, 3 x 60 s windows each, alternated on one running fleet): with
the agents and runtime inside the robot's quota the robot was throttled in 7-8 % of its 10 ms
periods and each nav-controller (30 Hz, hard real-time) missed 1.1 % of its cycles,
nav-localization 0.5 %; moved beside it, 2 % throttled and 0.02 % / 0-0.02 % missed, although
they used only 17-18 ms of CPU a second either way. Kubernetes draws the same line on a real
node: pods get the allocatable CPU, the system daemons run in the reserved rest.

Stopping a node kills every pid in its tree (by pid), then removes the directories deepest
first.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

from e2e.bed.base import HarnessError, log

CGROUP_ROOT = Path("/sys/fs/cgroup")
TOP = "fogfleet"
# A node's quota (on its pods) is enforced per 10 ms, not the kernel's default 100 ms: a 400m
# node then runs 4 ms of every 10 ms instead of stalling 60 ms of every 100 ms once it is busy,
# which is how a small computer (and the simulator's processor sharing) behaves, not a
# throttled container. A 33 ms cycle would otherwise miss on any stall. The kubelet's pod
# quotas below keep 100 ms.
CFS_PERIOD_US = 10_000
# The nodes are other computers: their CPU must not depend on how busy the control plane is.
# At the root the whole /fogfleet group weighs 1024, as much as ONE session of the host (the
# kernel's autogroups weigh each session alike), and the apiserver, etcd, Prometheus and the
# operator each run in their own session, so each weighed as much as all nodes: measured with
# warehouse-lite (k8s-default) on the 2-core VM, its 30 Hz modules then waited 140-190 ms per
# second for a CPU (schedstat run_delay) and missed 2-3 % of their cycles, human-pose
# estimation 7-11 %. With the group at the kernel's maximum weight it runs first, up to its
# nodes' quotas (which leave the control plane the rest): 1.0-1.2 % and 0.4-1.2 %.
TOP_CPU_SHARES = 262_144
SHARES_PER_CORE = 1024  # inside /fogfleet, a busy host is shared in proportion to node size
# Inside a node its pods outweigh its agents and runtime 64 to 1: they still get all the CPU
# the pods leave (the pods' quota caps them), but a burst of theirs no longer delays a module
# waking for its cycle. On the real computer that burst takes one of its cores for a moment;
# here, at equal weight, it took half the robot. Every node's kube-proxy and kube-router
# resync when a fleet's 40 pods and Services come or go anywhere in the cluster (measured
# 2026-11-28 during the leader-failover faults: 0.3-0.8 CPU seconds a second per node), and
# the ROS fleet on the robots missed 2-14 of ~1000 cycles per fault (8 faults, 4 of them in
# CI); with the pods first, 0-4 (6 faults; e2e/tests/test_faults_leader.py, bound 5).
POD_SHARES, AGENT_SHARES = 1024, 16


def _mounted(fstype: str) -> list[Path]:
    """Mount points of ``fstype`` (``cgroup`` for v1, ``cgroup2``) under /sys/fs/cgroup."""
    found = []
    for line in Path("/proc/self/mounts").read_text().splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[2] == fstype and parts[1].startswith(str(CGROUP_ROOT)):
            found.append(Path(parts[1]))
    return found


def hierarchies() -> list[Path]:
    """The mounted v1 hierarchies (cpu, memory, pids, ...), one directory each."""
    found = _mounted("cgroup")
    if not found:
        raise HarnessError("no cgroup v1 hierarchies under /sys/fs/cgroup: real nodes need them")
    return found


def every_hierarchy() -> list[Path]:
    """The v1 hierarchies and, on a hybrid host, the unified (cgroup2) one, where runc makes
    each container's cgroup as well: what a stopped bed must leave empty."""
    return [*hierarchies(), *_mounted("cgroup2")]


def node_path(node: str, sub: str = "") -> str:
    """The cgroup path (same in every hierarchy) of a node, or of one of its parts."""
    return f"/{TOP}/{node}" + (f"/{sub}" if sub else "")


def _mkdir(hierarchy: Path, path: str) -> Path:
    current = hierarchy
    for part in path.strip("/").split("/"):
        parent, current = current, current / part
        if not current.exists():
            current.mkdir()
            if hierarchy.name == "cpuset" or "cpuset" in hierarchy.name.split(","):
                for knob in ("cpuset.cpus", "cpuset.mems"):
                    (current / knob).write_text((parent / knob).read_text())
    return current


def create(node: str, cpu_millis: int, memory_bytes: int) -> None:
    """Make the node's tree in every hierarchy, its CPU weight and memory limit, and its pods'
    CPU quota."""
    for h in hierarchies():
        for sub in ("pods", "runtime", "agents"):
            _mkdir(h, node_path(node, sub))
    (CGROUP_ROOT / "cpu" / TOP / "cpu.shares").write_text(str(TOP_CPU_SHARES))
    cpu = CGROUP_ROOT / "cpu" / node_path(node).lstrip("/")
    (cpu / "cpu.shares").write_text(str(max(2, cpu_millis * SHARES_PER_CORE // 1000)))
    (cpu / "pods" / "cpu.shares").write_text(str(POD_SHARES))
    for sub in ("runtime", "agents"):
        (cpu / sub / "cpu.shares").write_text(str(AGENT_SHARES))
    (cpu / "pods" / "cpu.cfs_period_us").write_text(str(CFS_PERIOD_US))
    set_cpu_quota(node, cpu_millis)
    mem = CGROUP_ROOT / "memory" / node_path(node).lstrip("/")
    (mem / "memory.limit_in_bytes").write_text(str(memory_bytes))


def join_links(pid: int) -> None:
    """Move a link's delay line into ``/fogfleet/links``, weighted like the whole bed: the
    emulated network is not the control plane, and a delay line that waits for a CPU behind
    the nodes adds its wait to every packet's delay."""
    join(pid, f"/{TOP}/links")  # makes the group in every hierarchy
    (CGROUP_ROOT / "cpu" / TOP / "links" / "cpu.shares").write_text(str(TOP_CPU_SHARES))


def set_cpu_quota(node: str, cpu_millis: int | None) -> None:
    """The CFS quota of the node's pods (None: unlimited), e.g. lifted while images are
    preloaded."""
    cpu = CGROUP_ROOT / "cpu" / node_path(node, "pods").lstrip("/")
    quota = -1 if cpu_millis is None else cpu_millis * CFS_PERIOD_US // 1000
    (cpu / "cpu.cfs_quota_us").write_text(str(quota))


def join(pid: int, path: str) -> None:
    """Move `pid` into `path` in every hierarchy (children it forks follow)."""
    for h in hierarchies():
        target = _mkdir(h, path)
        (target / "cgroup.procs").write_text(str(pid))


def pids(path: str) -> set[int]:
    """Every pid anywhere below `path` (read from the pids or cpu hierarchy)."""
    out: set[int] = set()
    for h in hierarchies():
        base = h / path.lstrip("/")
        if not base.exists():
            continue
        for procs in base.rglob("cgroup.procs"):
            with contextlib.suppress(OSError):
                out.update(int(x) for x in procs.read_text().split())
    return out


def kill_all(path: str, timeout: float = 10) -> int:
    """SIGKILL every process below `path` until none is left; returns how many were killed."""
    killed: set[int] = set()
    deadline = time.monotonic() + timeout
    while True:
        left = pids(path)
        if not left:
            return len(killed)
        if time.monotonic() > deadline:
            raise HarnessError(f"cgroup {path}: pids {sorted(left)[:10]} survive SIGKILL")
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            killed.add(pid)
        time.sleep(0.1)


def remove(path: str) -> None:
    """rmdir the tree below `path` in every hierarchy, deepest first (empty cgroups only)."""
    for h in every_hierarchy():
        base = h / path.lstrip("/")
        if not base.exists():
            continue
        dirs = sorted((p for p in base.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts))
        for d in [*dirs, base]:
            with contextlib.suppress(OSError):
                d.rmdir()


def usage_seconds(path: str) -> float:
    """CPU time used below `path` (cpuacct.usage, nanoseconds -> seconds)."""
    f = CGROUP_ROOT / "cpuacct" / path.lstrip("/") / "cpuacct.usage"
    return int(f.read_text()) / 1e9


def teardown_all() -> None:
    """Kill and remove every node tree under /fogfleet (after `down`, or a crashed bed)."""
    top = f"/{TOP}"
    n = kill_all(top)
    remove(top)
    if n:
        log(f"cgroups: killed {n} leftover processes under {top}")
