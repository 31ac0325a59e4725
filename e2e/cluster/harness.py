#!/usr/bin/env python3
"""A real Kubernetes control plane for fogfleet's e2e tests, run as local processes (no Docker).

    python e2e/cluster/harness.py build | up | down | status
    python e2e/cluster/harness.py nodes [--robots N --edges M --cloud K]
    python e2e/cluster/harness.py kubectl ARGS... | helm ARGS...

Why it looks like this (see e2e/README.md and /work/shared/design/CLUSTER.md):

* Every binary is built from published Go modules (k8s.io/kubernetes through a wrapper module
  whose ``replace`` lines are generated from k8s's own go.mod, kwok, etcd, helm) or unpacked from
  Debian's ``prometheus`` package. Versions live in ``versions.env`` next to this file; builds
  are cached under ``${XDG_CACHE_HOME:-~/.cache}/fogfleet/tools/<tool>-<version>/`` and reused
  after a ``--version`` check. ``GOTOOLCHAIN=local`` always: a too-old Go fails at once.
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
import base64
import contextlib
import fcntl
import json
import os
import re
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "BIN_DIR",
    "CACHE_ROOT",
    "KUBECONFIG",
    "PROMETHEUS_TARGETS_DIR",
    "STATE_DIR",
    "Cluster",
    "HarnessError",
    "create_nodes",
    "down",
    "ensure_built",
    "ensure_up",
    "running",
]

HERE = Path(__file__).resolve().parent
VERSIONS_FILE = HERE / "versions.env"
NODES_FILE = HERE / "nodes.yaml"

CACHE_ROOT = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fogfleet"
TOOLS_DIR = CACHE_ROOT / "tools"
BIN_DIR = CACHE_ROOT / "bin"
STATE_DIR = CACHE_ROOT / "cluster"
KUBECONFIG = STATE_DIR / "kubeconfig"
PROMETHEUS_TARGETS_DIR = STATE_DIR / "prometheus-targets"
LOCK_FILE = CACHE_ROOT / "harness.lock"

HOST = "127.0.0.1"
COMPONENTS = (
    "etcd",
    "kube-apiserver",
    "kube-controller-manager",
    "kube-scheduler",
    "kwok",
    "prometheus",
)
# Preferred ports (a busy one is replaced by a free ephemeral port and recorded in state.json).
PREFERRED_PORTS = {
    "etcd": 23790,
    "etcd-peer": 23800,
    "kube-apiserver": 26443,
    "kube-controller-manager": 26257,
    "kube-scheduler": 26259,
    "kwok": 26250,
    "prometheus": 29090,
}
TOOLS = ("k8s", "etcd", "kwok", "helm", "prometheus")
K8S_COMMANDS = ("kube-apiserver", "kube-controller-manager", "kube-scheduler", "kubectl")

# Node health timing. kwok renews each node Lease every lease/4 seconds; the node-lifecycle
# controller marks a node whose Lease is older than the grace period Ready=Unknown and taints it.
NODE_LEASE_SECONDS = 10
NODE_MONITOR_PERIOD = "1s"
NODE_MONITOR_GRACE_PERIOD = "10s"
# Pods get NoExecute tolerations of this many seconds for not-ready/unreachable nodes (the
# upstream default is 300 s), so evictions from a failed node happen within a test's timeout.
POD_EVICTION_TOLERATION_SECONDS = 10
PROMETHEUS_SCRAPE_INTERVAL = "2s"

# kwok stops managing (heartbeating) a node that carries this label with the value "stopped".
HEARTBEAT_LABEL = "fogfleet.io/e2e-heartbeat"
# kwok's own chaos stage: a node with this label set to "true" reports Ready=False.
KWOK_NOT_READY_LABEL = "node-not-ready.stage.kwok.x-k8s.io"
KWOK_STAGES = (
    "stage/node/fast/node-initialize.yaml",
    "stage/node/heartbeat-with-lease/node-heartbeat-with-lease.yaml",
    "stage/node/chaos/node-not-ready.yaml",
    "stage/pod/fast/pod-ready.yaml",
    "stage/pod/fast/pod-complete.yaml",
    "stage/pod/fast/pod-delete.yaml",
)


class HarnessError(RuntimeError):
    """Anything that stops the harness: missing toolchain, registry outage, unhealthy process."""


# --------------------------------------------------------------------------------------------
# small helpers


_T0 = time.monotonic()


def log(msg: str) -> None:
    print(f"[harness {time.monotonic() - _T0:6.1f}s] {msg}", file=sys.stderr, flush=True)


def load_versions(path: Path = VERSIONS_FILE) -> dict[str, str]:
    versions: dict[str, str] = {}
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise HarnessError(f"{path}: bad line {raw!r}")
        versions[key.strip()] = value.strip()
    return versions


def run(
    cmd: Sequence[str | os.PathLike[str]],
    *,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
    log_file: Path | None = None,
    timeout: float | None = None,
    hint: str = "",
) -> str:
    """Run a command, return stdout+stderr; on failure raise HarnessError with the output tail."""
    argv = [str(c) for c in cmd]
    try:
        proc = subprocess.run(
            argv,
            cwd=cwd,
            env=dict(env) if env is not None else None,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=timeout,
            check=False,
        )
    except FileNotFoundError as exc:
        raise HarnessError(f"command not found: {argv[0]} {hint}".strip()) from exc
    except subprocess.TimeoutExpired as exc:
        raise HarnessError(f"timed out after {timeout}s: {' '.join(argv)}") from exc
    if log_file is not None:
        with log_file.open("a") as fh:
            fh.write(f"$ {' '.join(argv)}\n{proc.stdout}\n")
    if proc.returncode != 0:
        tail = "\n".join(proc.stdout.splitlines()[-40:])
        raise HarnessError(
            f"command failed (exit {proc.returncode}): {' '.join(argv)}\n{tail}\n{hint}".rstrip()
        )
    return proc.stdout


@contextlib.contextmanager
def locked() -> Iterator[None]:
    """Serialise build/up/down across processes (two pytest sessions, make in another shell)."""
    CACHE_ROOT.mkdir(parents=True, exist_ok=True)
    with LOCK_FILE.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def wait_for(what: str, check: Callable[[], bool], timeout: float, interval: float = 0.5) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            if check():
                return
        except Exception:  # a probe that raises counts as "not yet"
            pass
        if time.monotonic() > deadline:
            raise HarnessError(f"timed out after {timeout:.0f}s waiting for {what}")
        time.sleep(interval)


def http_get(url: str, *, context: ssl.SSLContext | None = None, timeout: float = 3) -> str:
    with urllib.request.urlopen(url, context=context, timeout=timeout) as resp:
        body: bytes = resp.read()
        return body.decode()


def insecure_tls() -> ssl.SSLContext:
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    return ctx


def port_is_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        # as the Go servers do: a port in TIME_WAIT from a previous run counts as free
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((HOST, port))
        except OSError:
            return False
        return True


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        port: int = s.getsockname()[1]
        return port


# --------------------------------------------------------------------------------------------
# build: one function per tool, each reusing its cache directory after a --version check


def _version_tuple(text: str) -> tuple[int, ...]:
    return tuple(int(x) for x in re.findall(r"\d+", text)[:3])


@dataclass
class GoToolchain:
    go: str
    env: dict[str, str]

    @classmethod
    def find(cls, versions: Mapping[str, str]) -> GoToolchain:
        go = shutil.which("go") or (
            "/usr/local/go/bin/go" if Path("/usr/local/go/bin/go").exists() else None
        )
        need = versions["GO_MIN_VERSION"]
        if go is None:
            raise HarnessError(
                f"Go toolchain not found: the e2e control plane is built from the Go module "
                f"proxy and needs Go >= {need} on PATH (https://go.dev/dl/)."
            )
        env = dict(os.environ, GOTOOLCHAIN="local", CGO_ENABLED="0", GOFLAGS="-buildvcs=false")
        have = run([go, "env", "GOVERSION"], env=env).strip()
        if _version_tuple(have) < _version_tuple(need):
            raise HarnessError(
                f"{go} is {have}; the pinned tools need Go >= {need} (GOTOOLCHAIN=local, "
                "so no toolchain is downloaded). Install a newer Go."
            )
        return cls(go=go, env=env)

    def __call__(
        self,
        *args: str,
        cwd: Path | None = None,
        log_file: Path | None = None,
        extra_env: Mapping[str, str] | None = None,
    ) -> str:
        env = dict(self.env, **(extra_env or {}))
        return run(
            [self.go, *args],
            cwd=cwd,
            env=env,
            log_file=log_file,
            hint=(
                "hint: is the Go module proxy reachable? "
                f"(GOPROXY={env.get('GOPROXY') or 'default'}); see the log above."
            ),
        )


def _version_ok(binary: Path, args: Sequence[str], expect: str) -> bool:
    if not binary.exists():
        return False
    try:
        out = subprocess.run(
            [str(binary), *args], capture_output=True, text=True, timeout=30, check=False
        )
    except OSError:
        return False
    return expect in out.stdout + out.stderr


@dataclass
class Tool:
    name: str
    root: Path
    binaries: dict[str, Path]
    checks: list[tuple[Path, list[str], str]] = field(default_factory=list)
    extra: dict[str, Path] = field(default_factory=dict)

    def ok(self) -> bool:
        return all(_version_ok(b, a, e) for b, a, e in self.checks) and all(
            p.exists() for p in self.extra.values()
        )


def tool_specs(v: Mapping[str, str]) -> dict[str, Tool]:
    kv, ev, kw, hv = v["K8S_VERSION"], v["ETCD_VERSION"], v["KWOK_VERSION"], v["HELM_VERSION"]
    pv = v["PROMETHEUS_DEB_VERSION"]
    k8s_root = TOOLS_DIR / f"k8s-{kv}"
    k8s = Tool("k8s", k8s_root, {c: k8s_root / "bin" / c for c in K8S_COMMANDS})
    for c in K8S_COMMANDS[:3]:
        k8s.checks.append((k8s.binaries[c], ["--version"], f"Kubernetes v{kv}"))
    k8s.checks.append((k8s.binaries["kubectl"], ["version", "--client"], f"Client Version: v{kv}"))
    etcd_root = TOOLS_DIR / f"etcd-{ev}"
    etcd = Tool("etcd", etcd_root, {"etcd": etcd_root / "bin" / "etcd"})
    etcd.checks.append((etcd.binaries["etcd"], ["--version"], f"etcd Version: {ev}"))
    kwok_root = TOOLS_DIR / f"kwok-{kw}"
    kwok = Tool("kwok", kwok_root, {"kwok": kwok_root / "bin" / "kwok"})
    kwok.checks.append((kwok.binaries["kwok"], ["--version"], f"kwok version v{kw}"))
    kwok.extra["stages"] = kwok_root / "stages.yaml"
    minor = kv.split(".")[1]
    helm_root = TOOLS_DIR / f"helm-{hv}-k8s1.{minor}"
    helm = Tool("helm", helm_root, {"helm": helm_root / "bin" / "helm"})
    helm.checks.append((helm.binaries["helm"], ["version", "--short"], f"v{hv}"))
    prom_root = TOOLS_DIR / f"prometheus-{pv.replace('+', '_').replace(':', '_')}"
    prom = Tool(
        "prometheus",
        prom_root,
        {
            "prometheus": prom_root / "pkg" / "usr" / "bin" / "prometheus",
            "promtool": prom_root / "pkg" / "usr" / "bin" / "promtool",
        },
    )
    prom.checks.append((prom.binaries["prometheus"], ["--version"], f"version {pv.split('+')[0]}"))
    return {"k8s": k8s, "etcd": etcd, "kwok": kwok, "helm": helm, "prometheus": prom}


def _staging_modules(gomod_text: str) -> list[str]:
    """k8s.io/* modules that k8s.io/kubernetes requires at v0.0.0 (its ./staging replaces)."""
    found = re.findall(r"^\s*(?:require\s+)?(k8s\.io/[\w.\-/]+)\s+v0\.0\.0\s*$", gomod_text, re.M)
    return sorted(set(found))


def _build_k8s(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    kv = v["K8S_VERSION"]
    major, minor, _ = kv.split(".")
    staging_version = f"v0.{minor}.{kv.split('.')[2]}"
    src = tool.root / "src"
    src.mkdir(parents=True, exist_ok=True)
    if not (src / "go.mod").exists():
        go("mod", "init", "e2e.local/k8sbins", cwd=src, log_file=blog)
    go("mod", "edit", f"-go={v['GO_MIN_VERSION']}", cwd=src, log_file=blog)
    info = json.loads(go("mod", "download", "-json", f"k8s.io/kubernetes@v{kv}", cwd=src))
    if info.get("Error"):
        raise HarnessError(f"go mod download k8s.io/kubernetes@v{kv}: {info['Error']}")
    staging = _staging_modules(Path(info["GoMod"]).read_text())
    if not staging:
        raise HarnessError(f"found no staging modules in {info['GoMod']}; go.mod format changed?")
    log(f"k8s: {len(staging)} staging modules -> {staging_version}")
    go(
        "mod",
        "edit",
        *[f"-replace={m}={m}@{staging_version}" for m in staging],
        cwd=src,
        log_file=blog,
    )
    cmds = [f"k8s.io/kubernetes/cmd/{c}" for c in K8S_COMMANDS]
    log("k8s: go get -tool (resolves the module graph, downloads modules)")
    go("get", "-tool", *[f"{c}@v{kv}" for c in cmds], cwd=src, log_file=blog)
    date = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    ldflags = ["-s", "-w"]
    for pkg in ("k8s.io/component-base/version", "k8s.io/client-go/pkg/version"):
        ldflags += [
            f"-X {pkg}.gitVersion=v{kv}",
            f"-X {pkg}.gitMajor={major}",
            f"-X {pkg}.gitMinor={minor}",
            f"-X {pkg}.gitTreeState=clean",
            f"-X {pkg}.gitCommit=go-module-build",
            f"-X {pkg}.buildDate={date}",
        ]
    (tool.root / "bin").mkdir(exist_ok=True)
    log("k8s: go build kube-apiserver kube-controller-manager kube-scheduler kubectl")
    go(
        "build",
        "-trimpath",
        "-ldflags",
        " ".join(ldflags),
        "-o",
        f"{tool.root / 'bin'}/",
        *cmds,
        cwd=src,
        log_file=blog,
    )


def _build_etcd(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    src = tool.root / "src"
    src.mkdir(parents=True, exist_ok=True)
    if not (src / "go.mod").exists():
        go("mod", "init", "e2e.local/etcdbin", cwd=src, log_file=blog)
    # etcd's server module has `replace` lines of its own, so `go install` refuses it; a
    # wrapper module that requires it works (its module root is a main package).
    go("get", "-tool", f"go.etcd.io/etcd/server/v3@v{v['ETCD_VERSION']}", cwd=src, log_file=blog)
    go(
        "build",
        "-trimpath",
        "-ldflags",
        "-s -w",
        "-o",
        str(tool.binaries["etcd"]),
        "go.etcd.io/etcd/server/v3",
        cwd=src,
        log_file=blog,
    )


def _build_kwok(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    kw = v["KWOK_VERSION"]
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    go(
        "install",
        f"sigs.k8s.io/kwok/cmd/kwok@v{kw}",
        log_file=blog,
        extra_env={"GOBIN": str(tool.root / "bin")},
    )
    # The node/pod lifecycle stages ship as YAML in kwok's module; read them from the module
    # cache (nothing of kwok is copied into the repository).
    info = json.loads(go("mod", "download", "-json", f"sigs.k8s.io/kwok@v{kw}"))
    if info.get("Error"):
        raise HarnessError(f"go mod download sigs.k8s.io/kwok@v{kw}: {info['Error']}")
    kustomize = Path(info["Dir"]) / "kustomize"
    docs = [(kustomize / rel).read_text().strip() for rel in KWOK_STAGES]
    tool.extra["stages"].write_text("\n---\n".join(docs) + "\n")


def _build_helm(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    hv, kv = v["HELM_VERSION"], v["K8S_VERSION"]
    major, minor = kv.split(".")[:2]
    ldflags = ["-s", "-w", f"-X helm.sh/helm/v3/internal/version.version=v{hv}"]
    for pkg in ("helm.sh/helm/v3/pkg/chartutil", "helm.sh/helm/v3/pkg/lint/rules"):
        ldflags += [f"-X {pkg}.k8sVersionMajor={major}", f"-X {pkg}.k8sVersionMinor={minor}"]
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    go(
        "install",
        "-trimpath",
        "-ldflags",
        " ".join(ldflags),
        f"helm.sh/helm/v3/cmd/helm@v{hv}",
        log_file=blog,
        extra_env={"GOBIN": str(tool.root / "bin")},
    )


def _build_prometheus(tool: Tool, v: Mapping[str, str], go: GoToolchain | None, blog: Path) -> None:
    pv = v["PROMETHEUS_DEB_VERSION"]
    for cmd in ("apt-get", "dpkg"):
        if shutil.which(cmd) is None:
            raise HarnessError(
                f"{cmd} not found: Prometheus comes from Debian's `prometheus` package "
                f"({pv}); run on Debian/Ubuntu or put a prometheus binary at "
                f"{tool.binaries['prometheus']}."
            )
    dl = tool.root / "download"
    shutil.rmtree(dl, ignore_errors=True)
    dl.mkdir(parents=True)
    spec = f"prometheus={pv}"
    try:
        run(["apt-get", "download", spec], cwd=dl, log_file=blog)
    except HarnessError:
        if os.geteuid() != 0:
            raise HarnessError(
                f"`apt-get download {spec}` failed; run `sudo apt-get update` and retry."
            ) from None
        log("prometheus: apt-get download failed; running apt-get update and retrying")
        run(
            ["apt-get", "update"],
            log_file=blog,
            timeout=600,
            hint="hint: is the Debian mirror reachable?",
        )
        run(
            ["apt-get", "download", spec],
            cwd=dl,
            log_file=blog,
            hint=(
                f"hint: Debian no longer carries {pv}? Update PROMETHEUS_DEB_VERSION in "
                f"{VERSIONS_FILE} to `apt-cache policy prometheus`'s candidate."
            ),
        )
    debs = sorted(dl.glob("prometheus_*.deb"))
    if not debs:
        raise HarnessError(f"apt-get download {spec} produced no .deb in {dl}")
    shutil.rmtree(tool.root / "pkg", ignore_errors=True)
    run(["dpkg", "-x", debs[0], tool.root / "pkg"], log_file=blog)
    shutil.rmtree(dl, ignore_errors=True)


BUILDERS: dict[str, Callable[..., None]] = {
    "k8s": _build_k8s,
    "etcd": _build_etcd,
    "kwok": _build_kwok,
    "helm": _build_helm,
    "prometheus": _build_prometheus,
}


def ensure_built(only: Sequence[str] = TOOLS, *, force: bool = False, quiet: bool = False) -> Path:
    """Build (or reuse) the pinned tools and link them into BIN_DIR; return BIN_DIR.

    Not locked by itself: callers from other processes go through `locked()`.
    """
    v = load_versions()
    specs = tool_specs(v)
    unknown = set(only) - set(TOOLS)
    if unknown:
        raise HarnessError(f"unknown tool(s) {sorted(unknown)}; choose from {TOOLS}")
    go: GoToolchain | None = None
    timings: list[tuple[str, float, str]] = []
    for name in TOOLS:
        if name not in only:
            continue
        tool = specs[name]
        t0 = time.monotonic()
        if not force and tool.ok():
            timings.append((name, time.monotonic() - t0, "cached"))
        else:
            if go is None and name != "prometheus":
                go = GoToolchain.find(v)
            tool.root.mkdir(parents=True, exist_ok=True)
            blog = tool.root / "build.log"
            blog.write_text("")
            log(f"{name}: building into {tool.root} (log: {blog})")
            BUILDERS[name](tool, v, go, blog)
            bad = [str(b) for b, a, e in tool.checks if not _version_ok(b, a, e)]
            if bad or not tool.ok():
                raise HarnessError(f"{name}: built, but the --version check failed for {bad}")
            timings.append((name, time.monotonic() - t0, "built"))
        if not (quiet and timings[-1][2] == "cached"):
            log(f"{name}: {timings[-1][2]} in {timings[-1][1]:.1f}s")
        BIN_DIR.mkdir(parents=True, exist_ok=True)
        for bin_name, path in tool.binaries.items():
            link = BIN_DIR / bin_name
            tmp = BIN_DIR / f".{bin_name}.tmp"
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(path)
            tmp.replace(link)
        for extra_name, path in tool.extra.items():
            link = BIN_DIR / f"kwok-{extra_name}.yaml"
            tmp = BIN_DIR / f".{link.name}.tmp"
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(path)
            tmp.replace(link)
    return BIN_DIR


# --------------------------------------------------------------------------------------------
# process bookkeeping


def _proc_starttime(pid: int) -> str | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()
    if fields[0] == "Z":
        return None
    return fields[19]  # field 22 of /proc/pid/stat: start time in clock ticks


def _pid_file(name: str) -> Path:
    return STATE_DIR / "pids" / f"{name}.pid"


def _read_pid(name: str) -> dict[str, Any] | None:
    try:
        rec: dict[str, Any] = json.loads(_pid_file(name).read_text())
    except (OSError, ValueError):
        return None
    return rec


def _alive(name: str) -> int | None:
    """The pid of component `name` if that exact process (pid + start time) still runs."""
    rec = _read_pid(name)
    if rec is None:
        return None
    pid = int(rec["pid"])
    if _proc_starttime(pid) != rec.get("starttime"):
        return None
    return pid


def _start(name: str, argv: Sequence[str | Path], env: Mapping[str, str] | None = None) -> int:
    logs = STATE_DIR / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    (STATE_DIR / "pids").mkdir(parents=True, exist_ok=True)
    log_path = logs / f"{name}.log"
    with log_path.open("ab") as out:
        out.write(f"# {time.ctime()}: {' '.join(map(str, argv))}\n".encode())
        out.flush()
        proc = subprocess.Popen(
            [str(a) for a in argv],
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=STATE_DIR,
            env=dict(env) if env is not None else None,
            start_new_session=True,
        )
    rec = {"pid": proc.pid, "argv0": str(argv[0]), "starttime": _proc_starttime(proc.pid)}
    _pid_file(name).write_text(json.dumps(rec) + "\n")
    log(f"{name}: started pid {proc.pid} (log: {log_path})")
    return proc.pid


def _stop(name: str, grace: float = 10) -> None:
    pid = _alive(name)
    if pid is None:
        _pid_file(name).unlink(missing_ok=True)
        return
    rec = _read_pid(name) or {}
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and _proc_starttime(pid) == rec.get("starttime"):
        time.sleep(0.1)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)  # reap, when the caller is the parent (pytest)
    if _proc_starttime(pid) == rec.get("starttime"):
        log(f"{name}: pid {pid} ignored SIGTERM for {grace:.0f}s; sending SIGKILL")
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    log(f"{name}: stopped pid {pid}")
    _pid_file(name).unlink(missing_ok=True)


def log_tail(name: str, lines: int = 40) -> str:
    path = STATE_DIR / "logs" / f"{name}.log"
    try:
        with path.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 200 * lines))
            text = fh.read().decode(errors="replace")
    except OSError:
        return f"(no log at {path})"
    return "\n".join(text.splitlines()[-lines:])


# --------------------------------------------------------------------------------------------
# cluster state, health and the Python API


def _read_state() -> dict[str, Any] | None:
    try:
        state: dict[str, Any] = json.loads((STATE_DIR / "state.json").read_text())
    except (OSError, ValueError):
        return None
    return state


def _health(name: str, ports: Mapping[str, int]) -> tuple[bool, str]:
    port = ports[name]
    try:
        if name == "etcd":
            body = http_get(f"http://{HOST}:{port}/health")
            return '"health":"true"' in body, body.strip()
        if name == "kube-apiserver":
            ctx = ssl.create_default_context(cafile=str(STATE_DIR / "pki" / "ca.crt"))
            body = http_get(f"https://{HOST}:{port}/readyz", context=ctx)
            return body.strip() == "ok", body.strip()
        if name in ("kube-controller-manager", "kube-scheduler", "kwok"):
            body = http_get(f"https://{HOST}:{port}/healthz", context=insecure_tls())
            return body.strip() == "ok", body.strip()
        if name == "prometheus":
            body = http_get(f"http://{HOST}:{port}/-/ready")
            return "Ready" in body, body.strip()
    except (OSError, urllib.error.URLError, ssl.SSLError) as exc:
        return False, str(getattr(exc, "reason", exc))
    raise HarnessError(f"unknown component {name}")


@dataclass(frozen=True)
class Cluster:
    """A running local control plane. Everything listens on 127.0.0.1."""

    state_dir: Path
    bin_dir: Path
    kubeconfig: Path
    api_server: str
    prometheus_url: str
    prometheus_targets_dir: Path
    ports: Mapping[str, int]

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> Cluster:
        ports = dict(state["ports"])
        return cls(
            state_dir=STATE_DIR,
            bin_dir=BIN_DIR,
            kubeconfig=KUBECONFIG,
            api_server=f"https://{HOST}:{ports['kube-apiserver']}",
            prometheus_url=f"http://{HOST}:{ports['prometheus']}",
            prometheus_targets_dir=PROMETHEUS_TARGETS_DIR,
            ports=ports,
        )

    @property
    def logs_dir(self) -> Path:
        return self.state_dir / "logs"

    def health(self) -> dict[str, tuple[bool, str]]:
        return {c: _health(c, self.ports) for c in COMPONENTS}

    def kubectl(
        self, *args: str, input: str | None = None, check: bool = True, timeout: float = 120
    ) -> subprocess.CompletedProcess[str]:
        """Run the harness's kubectl against this cluster (stdout/stderr captured as text)."""
        proc = subprocess.run(
            [str(self.bin_dir / "kubectl"), f"--kubeconfig={self.kubeconfig}", *args],
            input=input,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
        if check and proc.returncode != 0:
            raise HarnessError(f"kubectl {' '.join(args)} failed: {proc.stderr.strip()}")
        return proc

    def kubectl_json(self, *args: str) -> Any:
        return json.loads(self.kubectl(*args, "-o", "json").stdout)

    def add_prometheus_target(
        self, name: str, address: str, labels: Mapping[str, str] | None = None
    ) -> Path:
        """Make Prometheus scrape http://<address>/metrics (job=<name>) within a few seconds.

        Only loopback addresses are accepted: nothing on this network may be scraped.
        """
        host = address.rsplit(":", 1)[0]
        if host not in (HOST, "localhost"):
            raise HarnessError(f"refusing scrape target {address!r}: only {HOST} is allowed")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            raise HarnessError(f"bad target name {name!r}")
        self.prometheus_targets_dir.mkdir(parents=True, exist_ok=True)
        group = [{"targets": [address], "labels": {"job": name, **(labels or {})}}]
        path = self.prometheus_targets_dir / f"{name}.json"
        tmp = self.prometheus_targets_dir / f".{name}.tmp"
        tmp.write_text(json.dumps(group, indent=1) + "\n")
        tmp.replace(path)  # atomic: Prometheus never reads a half-written file
        return path

    def remove_prometheus_target(self, name: str) -> None:
        (self.prometheus_targets_dir / f"{name}.json").unlink(missing_ok=True)

    def prometheus_query(self, promql: str) -> list[dict[str, Any]]:
        """Instant query; returns the `result` vector (raises on a Prometheus error)."""
        url = f"{self.prometheus_url}/api/v1/query?" + urllib.parse.urlencode({"query": promql})
        body = json.loads(http_get(url, timeout=10))
        if body.get("status") != "success":
            raise HarnessError(f"Prometheus query {promql!r} failed: {body}")
        result: list[dict[str, Any]] = body["data"]["result"]
        return result

    def set_node_not_ready(self, node: str, not_ready: bool = True) -> None:
        """kwok's chaos stage: the node reports Ready=False (kubelet says "not ready").

        The Lease is still renewed; the node-lifecycle controller taints the node
        node.kubernetes.io/not-ready within about a second. `not_ready=False` recovers it.
        """
        value = f"{KWOK_NOT_READY_LABEL}=true" if not_ready else f"{KWOK_NOT_READY_LABEL}-"
        self.kubectl("label", "node", node, value, "--overwrite")

    def stop_node_heartbeat(self, node: str) -> None:
        """kwok stops managing the node (no Lease renewals, no status): a lost node.

        After NODE_MONITOR_GRACE_PERIOD the node-lifecycle controller sets Ready=Unknown and
        taints it node.kubernetes.io/unreachable (NoSchedule + NoExecute).
        """
        self.kubectl("label", "node", node, f"{HEARTBEAT_LABEL}=stopped", "--overwrite")

    def resume_node_heartbeat(self, node: str) -> None:
        self.kubectl("label", "node", node, f"{HEARTBEAT_LABEL}-")

    def log_tail(self, component: str, lines: int = 40) -> str:
        return log_tail(component, lines)


def running() -> Cluster | None:
    """The running cluster if every component is healthy, else None (never starts anything)."""
    state = _read_state()
    if state is None or state.get("phase") != "running":
        return None
    cluster = Cluster.from_state(state)
    if all(_alive(c) for c in COMPONENTS) and all(ok for ok, _ in cluster.health().values()):
        return cluster
    return None


# --------------------------------------------------------------------------------------------
# up


def _openssl(*args: str | Path) -> None:
    run(["openssl", *args], cwd=STATE_DIR / "pki", hint="hint: openssl is needed for the PKI")


def _make_pki() -> None:
    pki = STATE_DIR / "pki"
    pki.mkdir(parents=True, exist_ok=True)
    _openssl(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "3650",
        "-subj",
        "/CN=fogfleet-e2e-ca",
        "-keyout",
        "ca.key",
        "-out",
        "ca.crt",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign,cRLSign,digitalSignature",
    )
    _openssl(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-subj",
        "/O=system:masters/CN=fogfleet-e2e-admin",
        "-keyout",
        "admin.key",
        "-out",
        "admin.csr",
    )
    (pki / "ext.cnf").write_text(
        "subjectAltName=IP:127.0.0.1,DNS:localhost,DNS:kubernetes,DNS:kubernetes.default,"
        "DNS:kubernetes.default.svc,DNS:kubernetes.default.svc.cluster.local\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        "keyUsage=critical,digitalSignature,keyEncipherment\n"
        "basicConstraints=CA:FALSE\n"
    )
    _openssl(
        "x509",
        "-req",
        "-in",
        "admin.csr",
        "-CA",
        "ca.crt",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-days",
        "3650",
        "-extfile",
        "ext.cnf",
        "-out",
        "admin.crt",
    )
    _openssl("genrsa", "-out", "sa.key", "2048")
    for key in pki.glob("*.key"):
        key.chmod(0o600)


def _b64(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def _write_kubeconfig(api_server: str) -> None:
    pki = STATE_DIR / "pki"
    cfg = {
        "apiVersion": "v1",
        "kind": "Config",
        "clusters": [
            {
                "name": "fogfleet-e2e",
                "cluster": {
                    "server": api_server,
                    "certificate-authority-data": _b64(pki / "ca.crt"),
                },
            }
        ],
        "users": [
            {
                "name": "fogfleet-e2e-admin",
                "user": {
                    "client-certificate-data": _b64(pki / "admin.crt"),
                    "client-key-data": _b64(pki / "admin.key"),
                },
            }
        ],
        "contexts": [
            {
                "name": "fogfleet-e2e",
                "context": {"cluster": "fogfleet-e2e", "user": "fogfleet-e2e-admin"},
            }
        ],
        "current-context": "fogfleet-e2e",
    }
    KUBECONFIG.write_text(json.dumps(cfg, indent=1) + "\n")  # JSON is valid YAML
    KUBECONFIG.chmod(0o600)


def _prometheus_config(ports: Mapping[str, int]) -> dict[str, Any]:
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

    return {
        "global": {
            "scrape_interval": PROMETHEUS_SCRAPE_INTERVAL,
            "scrape_timeout": PROMETHEUS_SCRAPE_INTERVAL,
            "evaluation_interval": PROMETHEUS_SCRAPE_INTERVAL,
        },
        "scrape_configs": [
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
        ],
    }


def _argv(ports: Mapping[str, int]) -> dict[str, tuple[list[str], dict[str, str] | None]]:
    b, s, pki = BIN_DIR, STATE_DIR, STATE_DIR / "pki"
    kc = str(KUBECONFIG)
    allow = "--authorization-always-allow-paths=/healthz,/readyz,/livez,/metrics"
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
                "--service-cluster-ip-range=10.96.0.0/16",
                "--authorization-mode=Node,RBAC",
                "--allow-privileged=true",
                "--kubelet-preferred-address-types=Hostname",
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
                allow,
                "--leader-elect=false",
                f"--root-ca-file={pki / 'ca.crt'}",
                f"--service-account-private-key-file={pki / 'sa.key'}",
                f"--cluster-signing-cert-file={pki / 'ca.crt'}",
                f"--cluster-signing-key-file={pki / 'ca.key'}",
                f"--node-monitor-period={NODE_MONITOR_PERIOD}",
                f"--node-monitor-grace-period={NODE_MONITOR_GRACE_PERIOD}",
                f"--cert-dir={s / 'certs' / 'kcm'}",
            ],
            None,
        ),
        "kube-scheduler": (
            [
                str(b / "kube-scheduler"),
                f"--config={s / 'scheduler.yaml'}",
                f"--authentication-kubeconfig={kc}",
                f"--authorization-kubeconfig={kc}",
                f"--bind-address={HOST}",
                f"--secure-port={ports['kube-scheduler']}",
                allow,
                f"--cert-dir={s / 'certs' / 'scheduler'}",
            ],
            None,
        ),
        "kwok": (
            [
                str(b / "kwok"),
                f"--kubeconfig={kc}",
                f"--config={s / 'kwok.yaml'}",
                f"--manage-nodes-with-label-selector={HEARTBEAT_LABEL}!=stopped",
                "--node-name=localhost",
                "--node-ip=",
                f"--node-port={ports['kwok']}",
                f"--server-address={HOST}:{ports['kwok']}",
                f"--tls-cert-file={pki / 'admin.crt'}",
                f"--tls-private-key-file={pki / 'admin.key'}",
                f"--node-lease-duration-seconds={NODE_LEASE_SECONDS}",
                "--cidr=10.0.0.0/16",
                "--v=WARN",  # INFO logs every Lease renewal (about 10 MB an hour)
            ],
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


def _write_configs(ports: Mapping[str, int]) -> None:
    for d in ("logs", "pids", "certs", "kwok", "prometheus-data"):
        (STATE_DIR / d).mkdir(parents=True, exist_ok=True)
    PROMETHEUS_TARGETS_DIR.mkdir(parents=True, exist_ok=True)
    _make_pki()
    _write_kubeconfig(f"https://{HOST}:{ports['kube-apiserver']}")
    (STATE_DIR / "scheduler.yaml").write_text(
        json.dumps(
            {
                "apiVersion": "kubescheduler.config.k8s.io/v1",
                "kind": "KubeSchedulerConfiguration",
                "clientConnection": {"kubeconfig": str(KUBECONFIG)},
                "leaderElection": {"leaderElect": False},
            },
            indent=1,
        )
        + "\n"
    )
    stages = (BIN_DIR / "kwok-stages.yaml").read_text()
    # Only Stage documents: a KwokConfiguration document here would replace kwok's defaults
    # (v0.8.0 then fails with "node leases parallelism must be greater than 0"); flags suffice.
    (STATE_DIR / "kwok.yaml").write_text(stages)
    (STATE_DIR / "prometheus.yml").write_text(json.dumps(_prometheus_config(ports), indent=1))
    run([BIN_DIR / "promtool", "check", "config", STATE_DIR / "prometheus.yml"])


def _write_state(ports: Mapping[str, int], phase: str) -> None:
    state = {
        "phase": phase,
        "ports": dict(ports),
        "versions": load_versions(),
        "api_server": f"https://{HOST}:{ports['kube-apiserver']}",
        "kubeconfig": str(KUBECONFIG),
        "prometheus_url": f"http://{HOST}:{ports['prometheus']}",
        "prometheus_targets_dir": str(PROMETHEUS_TARGETS_DIR),
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


def _wait_healthy(name: str, ports: Mapping[str, int]) -> None:
    def check() -> bool:
        if _alive(name) is None:
            raise HarnessError(f"{name} exited during start-up; log tail:\n{log_tail(name)}")
        return _health(name, ports)[0]

    deadline = time.monotonic() + _START_TIMEOUTS[name]
    t0 = time.monotonic()
    while not check():
        if time.monotonic() > deadline:
            raise HarnessError(
                f"{name} not healthy after {_START_TIMEOUTS[name]}s "
                f"({_health(name, ports)[1]}); log tail:\n{log_tail(name)}"
            )
        time.sleep(0.3)
    log(f"{name}: healthy after {time.monotonic() - t0:.1f}s")


def _stop_all() -> None:
    for name in reversed(COMPONENTS):
        _stop(name)


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


# --------------------------------------------------------------------------------------------
# nodes


def node_object(
    name: str, tier: str, hardware: str, cpu: int, memory_gi: int, robot: str | None = None
) -> dict[str, Any]:
    """A fake Node as in nodes.yaml (kwok fills conditions and addresses)."""
    labels = {
        "kubernetes.io/hostname": name,
        "kubernetes.io/os": "linux",
        "kubernetes.io/arch": "amd64",
        "fogfleet.io/tier": tier,
        "fogfleet.io/hardware-type": hardware,
    }
    if robot is not None:
        labels["fogfleet.io/robot"] = robot
    resources = {"cpu": str(cpu), "memory": f"{memory_gi}Gi", "pods": "110"}
    return {
        "apiVersion": "v1",
        "kind": "Node",
        "metadata": {
            "name": name,
            "labels": labels,
            "annotations": {"kwok.x-k8s.io/node": "fake", "node.alpha.kubernetes.io/ttl": "0"},
        },
        "status": {"allocatable": resources, "capacity": dict(resources)},
    }


def generated_nodes(robots: int, edges: int, cloud: int) -> list[dict[str, Any]]:
    """robot-1..N (robot-nuc), edge-1..M (first half dsv3-16, rest fsv2-8), cloud-1..K."""
    out = [
        node_object(f"robot-{i}", "robot", "robot-nuc", 8, 16, robot=f"robot-{i}")
        for i in range(1, robots + 1)
    ]
    big = (edges + 1) // 2
    for i in range(1, edges + 1):
        if i <= big:
            out.append(node_object(f"edge-{i}", "edge", "dsv3-16", 16, 64))
        else:
            out.append(node_object(f"edge-{i}", "edge", "fsv2-8", 8, 16))
    out += [node_object(f"cloud-{i}", "cloud", "fsv2-32", 32, 128) for i in range(1, cloud + 1)]
    return out


def _nodes_ready(cluster: Cluster, names: set[str]) -> bool:
    items = cluster.kubectl_json("get", "nodes")["items"]
    ready = set()
    for node in items:
        conds = {c["type"]: c["status"] for c in node.get("status", {}).get("conditions", [])}
        if conds.get("Ready") == "True" and not node.get("spec", {}).get("taints"):
            ready.add(node["metadata"]["name"])
    return names <= ready


def _apply_nodes(cluster: Cluster, manifest: str, timeout: float = 120) -> list[str]:
    out = cluster.kubectl("apply", "-f", "-", "-o", "name", input=manifest).stdout
    names = {line.split("/", 1)[1] for line in out.split() if line.startswith("node/")}
    t0 = time.monotonic()
    wait_for(
        f"{len(names)} nodes Ready and untainted", lambda: _nodes_ready(cluster, names), timeout
    )
    log(f"{len(names)} nodes Ready and untainted after {time.monotonic() - t0:.1f}s")
    return sorted(names)


def create_nodes(robots: int | None = None, edges: int | None = None, cloud: int = 1) -> list[str]:
    """Replace every Node with a generated set (or nodes.yaml when no counts are given)."""
    cluster = running()
    if cluster is None:
        raise HarnessError("the cluster is not running; run `harness.py up` first")
    if robots is None and edges is None:
        manifest = NODES_FILE.read_text()
    else:
        items = generated_nodes(robots or 0, edges or 0, cloud)
        manifest = json.dumps({"apiVersion": "v1", "kind": "List", "items": items})
    cluster.kubectl("delete", "nodes", "--all", "--wait=true", timeout=300)
    return _apply_nodes(cluster, manifest, timeout=300)


# --------------------------------------------------------------------------------------------
# down / status / CLI


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


def _exec(argv: list[str], env: Mapping[str, str] | None = None) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(argv[0], argv, dict(env if env is not None else os.environ))


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    # passthroughs first: their arguments are not ours to parse
    if args and args[0] == "kubectl":
        with locked():
            ensure_built(["k8s"], quiet=True)
        if not KUBECONFIG.exists():
            raise HarnessError("no cluster: run `harness.py up` first")
        _exec([str(BIN_DIR / "kubectl"), f"--kubeconfig={KUBECONFIG}", *args[1:]])
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
    b.add_argument("--only", default=",".join(TOOLS), help=f"comma list of {','.join(TOOLS)}")
    b.add_argument("--force", action="store_true", help="rebuild even when cached")
    sub.add_parser("up", help="start the control plane (idempotent)")
    sub.add_parser("down", help="stop the control plane and remove its state")
    sub.add_parser("status", help="components, pids, ports, health")
    n = sub.add_parser("nodes", help="replace the fake nodes (default: nodes.yaml)")
    n.add_argument("--robots", type=int)
    n.add_argument("--edges", type=int)
    n.add_argument("--cloud", type=int, default=1)
    sub.add_parser("kubectl", help="kubectl ARGS... with the test kubeconfig")
    sub.add_parser("helm", help="helm ARGS... (cached helm binary)")
    ns = parser.parse_args(args)

    if ns.cmd == "build":
        with locked():
            t0 = time.monotonic()
            bin_dir = ensure_built([t for t in ns.only.split(",") if t], force=ns.force)
        log(f"tools ready in {bin_dir} ({time.monotonic() - t0:.1f}s)")
        return 0
    if ns.cmd == "up":
        cluster = ensure_up()
        print(f"kubeconfig: {cluster.kubeconfig}")
        print(f"api server: {cluster.api_server}")
        print(f"prometheus: {cluster.prometheus_url}")
        print(f"export KUBECONFIG={cluster.kubeconfig}")
        return 0
    if ns.cmd == "down":
        down()
        return 0
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
