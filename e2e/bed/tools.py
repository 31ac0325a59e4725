"""Build (or reuse from the cache) every pinned tool of the local cluster.

Each tool is built from published Go modules into ``TOOLS_DIR/<tool>-<version>/`` and reused
after a ``--version`` check: Kubernetes, etcd, kwok, helm, Prometheus (only its kubernetes_sd)
and CoreDNS (only the plugins the bed uses) from the bed's one Go module (``gomodule``, which
says why one), kube-router on its own, and for the cloud cluster only, Open Cluster Management
in a module of its own (``ocm.build``). Only the real nodes' runtime comes from Debian packages.
``GOTOOLCHAIN=local`` always: a too-old Go fails at once.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from e2e.bed import ocm
from e2e.bed.base import (
    BIN_DIR,
    CACHE_ROOT,
    TOOLS_DIR,
    HarnessError,
    load_versions,
    locked,
    log,
    run,
)
from e2e.bed.gomodule import (
    K8S_COMMANDS,
    MODULE_TOOLS,
    GoToolchain,
    ensure_module,
    module_dir,
    prometheus_module_version,
)

TOOLS = ("k8s", "etcd", "kwok", "helm", "prometheus", "coredns", "node-runtime", "kube-router")
# Built only for the cloud cluster (``bed.ensure_cloud``): nothing of the default bed uses them.
CLOUD_TOOLS = ("ocm",)
# Debian packages a real node runs on (the kubelet and kube-proxy come from the k8s build).
# ipset: kube-router's NetworkPolicy firewall keeps each policy's peers in ip sets.
NODE_PACKAGES = ("containerd", "runc", "containernetworking-plugins", "iptables", "ipset")
# Of Prometheus's service discoveries only kubernetes_sd (plugins/plugin_*.go honour the tags).
PROMETHEUS_TAGS = "remove_all_sd,enable_kubernetes_sd"

# Node health timing. kwok renews each node Lease every lease/4 seconds; the node-lifecycle
KWOK_STAGES = (
    "stage/node/fast/node-initialize.yaml",
    "stage/node/heartbeat-with-lease/node-heartbeat-with-lease.yaml",
    "stage/node/chaos/node-not-ready.yaml",
    "stage/pod/fast/pod-ready.yaml",
    "stage/pod/fast/pod-complete.yaml",
    "stage/pod/fast/pod-delete.yaml",
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
    files: list[Path] = field(default_factory=list)
    # a tool of the bed's Go module: a file that names the module it was built from, so that a
    # binary built another way (or from another module) is built again
    stamp: Path | None = None

    def ok(self) -> bool:
        return (
            all(_version_ok(b, a, e) for b, a, e in self.checks)
            and all(p.exists() for p in self.extra.values())
            and all(p.exists() for p in self.files)
            and (self.stamp is None or self.stamp.exists())
        )

    def stamp_built(self) -> None:
        if self.stamp is not None:
            for old in self.root.glob("built-from-*"):
                old.unlink()
            self.stamp.write_text(f"{self.stamp.name.removeprefix('built-from-')}\n")


def tool_specs(v: Mapping[str, str]) -> dict[str, Tool]:
    kv, ev, kw, hv = v["K8S_VERSION"], v["ETCD_VERSION"], v["KWOK_VERSION"], v["HELM_VERSION"]
    pv, cv = v["PROMETHEUS_VERSION"], v["COREDNS_VERSION"]
    k8s_root = TOOLS_DIR / f"k8s-{kv}"
    k8s = Tool("k8s", k8s_root, {c: k8s_root / "bin" / c for c in K8S_COMMANDS})
    for c in K8S_COMMANDS:
        if c != "kubectl":
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
    prom_root = TOOLS_DIR / f"prometheus-{pv}"
    prom_commands = ("prometheus", "promtool")
    prom = Tool("prometheus", prom_root, {c: prom_root / "bin" / c for c in prom_commands})
    for c in prom_commands:
        # the tags line proves the build: a Prometheus with every SD compiled in is not ours
        prom.checks.append((prom.binaries[c], ["--version"], f"{c}, version {pv} "))
        prom.checks.append((prom.binaries[c], ["--version"], PROMETHEUS_TAGS))
    coredns_root = TOOLS_DIR / f"coredns-{cv}"
    coredns = Tool("coredns", coredns_root, {"coredns": coredns_root / "bin" / "coredns"})
    coredns.checks.append((coredns.binaries["coredns"], ["-version"], f"CoreDNS-{cv}"))
    coredns.checks.append((coredns.binaries["coredns"], ["-plugins"], "\nkubernetes\n"))
    runtime = Tool("node-runtime", TOOLS_DIR / "node-runtime", {})
    runtime.checks += [
        (Path("/usr/bin/containerd"), ["--version"], "containerd"),
        (Path("/usr/sbin/runc"), ["--version"], "runc version"),
        (Path("/usr/bin/ctr"), ["--version"], "ctr"),
        (Path("/usr/sbin/iptables"), ["--version"], "iptables"),
    ]
    runtime.files += [Path("/usr/lib/cni/bridge"), Path("/usr/lib/cni/host-local")]
    runtime.files.append(Path("/usr/sbin/ipset"))
    krv = v["KUBE_ROUTER_VERSION"]
    kr_root = TOOLS_DIR / f"kube-router-{krv}"
    kube_router = Tool("kube-router", kr_root, {"kube-router": kr_root / "bin" / "kube-router"})
    kube_router.checks.append((kube_router.binaries["kube-router"], ["--version"], f"v{krv}"))
    ov = v["OCM_VERSION"]
    ocm_root = TOOLS_DIR / f"ocm-{ov}"
    ocm_tool = Tool("ocm", ocm_root, {c: ocm_root / "bin" / c for c in ocm.COMMANDS})
    for c in ocm.COMMANDS:
        ocm_tool.checks.append((ocm_tool.binaries[c], ["--version"], f"version v{ov}"))
    ocm_tool.files += [ocm_root / "manifests" / name for name in (*ocm.MANIFESTS, "bootstrap")]
    specs = {
        "k8s": k8s,
        "etcd": etcd,
        "kwok": kwok,
        "helm": helm,
        "prometheus": prom,
        "coredns": coredns,
        "node-runtime": runtime,
        "kube-router": kube_router,
        "ocm": ocm_tool,
    }
    stamp = f"built-from-{module_dir(v).name}"
    for name in MODULE_TOOLS:
        specs[name].stamp = specs[name].root / stamp
    return specs


def _module_build(
    go: GoToolchain,
    v: Mapping[str, str],
    blog: Path,
    out: Path,
    packages: Sequence[str],
    ldflags: Sequence[str] = (),
    tags: str = "",
) -> None:
    """``go build`` of ``packages`` in the bed's Go module (``gomodule``) into ``out`` (a file,
    or an existing directory for several packages), each package named in the log as it
    compiles."""
    src = ensure_module(v, go, blog)
    go(
        "build",
        "-v",
        "-trimpath",
        *(["-tags", tags] if tags else []),
        "-ldflags",
        " ".join(["-s", "-w", *ldflags]),
        "-o",
        str(out),
        *packages,
        cwd=src,
        log_file=blog,
    )


def _build_k8s(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    kv = v["K8S_VERSION"]
    major, minor, _ = kv.split(".")
    date = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    ldflags = []
    for pkg in ("k8s.io/component-base/version", "k8s.io/client-go/pkg/version"):
        ldflags += [
            f"-X {pkg}.gitVersion=v{kv}",
            f"-X {pkg}.gitMajor={major}",
            f"-X {pkg}.gitMinor={minor}",
            f"-X {pkg}.gitTreeState=clean",
            f"-X {pkg}.gitCommit=go-module-build",
            f"-X {pkg}.buildDate={date}",
        ]
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    cmds = [f"k8s.io/kubernetes/cmd/{c}" for c in K8S_COMMANDS]
    _module_build(go, v, blog, tool.root / "bin", cmds, ldflags)


def _build_etcd(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    # etcd's server module root is its main package
    _module_build(go, v, blog, tool.binaries["etcd"], ["go.etcd.io/etcd/server/v3"])


def _build_kwok(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    _module_build(go, v, blog, tool.binaries["kwok"], ["sigs.k8s.io/kwok/cmd/kwok"])
    # The node/pod lifecycle stages ship as YAML in kwok's module; read them from the module
    # cache (nothing of kwok is copied into the repository).
    kustomize = Path(go.download(f"sigs.k8s.io/kwok@v{v['KWOK_VERSION']}")["Dir"])
    docs = [(kustomize / "kustomize" / rel).read_text().strip() for rel in KWOK_STAGES]
    tool.extra["stages"].write_text("\n---\n".join(docs) + "\n")


def _build_helm(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    hv, kv = v["HELM_VERSION"], v["K8S_VERSION"]
    major, minor = kv.split(".")[:2]
    ldflags = [f"-X helm.sh/helm/v3/internal/version.version=v{hv}"]
    for pkg in ("helm.sh/helm/v3/pkg/chartutil", "helm.sh/helm/v3/pkg/lint/rules"):
        ldflags += [f"-X {pkg}.k8sVersionMajor={major}", f"-X {pkg}.k8sVersionMinor={minor}"]
    _module_build(go, v, blog, tool.binaries["helm"], ["helm.sh/helm/v3/cmd/helm"], ldflags)


def _build_prometheus(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """cmd/prometheus and cmd/promtool with only kubernetes_sd of the service discoveries (the
    ``plugins/plugin_*.go`` files honour the tags). The web UI's assets are not in the module
    (they come from an npm build): the API, which is all the bed and the operator use, works."""
    pv = v["PROMETHEUS_VERSION"]
    ldflags = []
    for key, value in (("Version", pv), ("Revision", prometheus_module_version(pv)),
                       ("Branch", "go-module-build")):  # fmt: skip
        ldflags.append(f"-X github.com/prometheus/common/version.{key}={value}")
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    packages = [f"github.com/prometheus/prometheus/cmd/{c}" for c in ("prometheus", "promtool")]
    _module_build(go, v, blog, tool.root / "bin", packages, ldflags, PROMETHEUS_TAGS)


def _build_coredns(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """The module's ``coredns/`` main package (``gomodule.coredns_main``): CoreDNS's documented
    way to build with a chosen plugin set, without editing plugin.cfg in a checkout."""
    _module_build(go, v, blog, tool.binaries["coredns"], ["./coredns"])


def _build_kube_router(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """kube-router, run by the real nodes only as a NetworkPolicy firewall (realnodes.py); built
    apart from the bed's module (``gomodule`` says why)."""
    krv = v["KUBE_ROUTER_VERSION"]
    module = "github.com/cloudnativelabs/kube-router/v2"
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    go(
        "install",
        "-v",
        "-trimpath",
        "-ldflags",
        f"-s -w -X {module}/pkg/version.Version=v{krv}",
        f"{module}/cmd/kube-router@v{krv}",
        log_file=blog,
        extra_env={"GOBIN": str(tool.root / "bin")},
    )


APT_LOCK_WAIT_SECONDS = 600  # another apt-get (a user's) holding dpkg's lock
APT_LOCK_FILE = CACHE_ROOT / "apt.lock"


def install_debian_packages(packages: Sequence[str], blog: Path | None = None) -> None:
    """apt-get install what is missing, as root, without starting any service.

    Debian's containerd would otherwise start a daemon on /run/containerd; a policy-rc.d that
    answers 101 keeps every package's service down (the bed starts its own, per node). The
    tools and the images build side by side (``make demo``): one install at a time, so that
    one build's policy-rc.d is never removed under the other's apt-get.
    """
    with locked(APT_LOCK_FILE):
        _install_missing(packages, blog)


def _install_missing(packages: Sequence[str], blog: Path | None) -> None:
    missing = [
        p
        for p in packages
        if subprocess.run(
            ["dpkg-query", "-W", "-f=${Status}", p], capture_output=True, text=True, check=False
        ).stdout.strip()
        != "install ok installed"
    ]
    if not missing:
        return
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        raise HarnessError(
            f"the bed needs the Debian packages {' '.join(missing)}: install them as root "
            f"(apt-get install {' '.join(missing)})"
        )
    policy = Path("/usr/sbin/policy-rc.d")
    had_policy = policy.exists()
    if not had_policy:
        policy.write_text("#!/bin/sh\n# fogfleet bed: packages never start services\nexit 101\n")
        policy.chmod(0o755)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    apt = ["apt-get", "-o", f"DPkg::Lock::Timeout={APT_LOCK_WAIT_SECONDS}"]
    install = [*apt, "install", "-y", "--no-install-recommends", *missing]
    try:
        try:
            run(install, env=env, log_file=blog, timeout=900)
        except HarnessError:
            log("apt-get install failed; running apt-get update and retrying")
            run([*apt, "update"], env=env, log_file=blog, timeout=600)
            run(install, env=env, log_file=blog, timeout=900)
    finally:
        if not had_policy:
            policy.unlink(missing_ok=True)
    log(f"installed Debian packages: {' '.join(missing)}")


def _build_node_runtime(tool: Tool, v: Mapping[str, str], go: object, blog: Path) -> None:
    install_debian_packages(NODE_PACKAGES, blog)


BUILDERS: dict[str, Callable[..., None]] = {
    "node-runtime": _build_node_runtime,
    "k8s": _build_k8s,
    "etcd": _build_etcd,
    "kwok": _build_kwok,
    "helm": _build_helm,
    "prometheus": _build_prometheus,
    "coredns": _build_coredns,
    "kube-router": _build_kube_router,
    "ocm": ocm.build,
}


def ensure_built(only: Sequence[str] = TOOLS, *, force: bool = False, quiet: bool = False) -> Path:
    """Build (or reuse) the pinned tools and link them into BIN_DIR; return BIN_DIR.

    Not locked by itself: callers from other processes go through `locked()`.
    """
    v = load_versions()
    specs = tool_specs(v)
    unknown = set(only) - set(TOOLS) - set(CLOUD_TOOLS)
    if unknown:
        raise HarnessError(
            f"unknown tool(s) {sorted(unknown)}; choose from {(*TOOLS, *CLOUD_TOOLS)}"
        )
    go: GoToolchain | None = None
    timings: list[tuple[str, float, str]] = []
    for name in (*TOOLS, *CLOUD_TOOLS):
        if name not in only:
            continue
        tool = specs[name]
        t0 = time.monotonic()
        if not force and tool.ok():
            timings.append((name, time.monotonic() - t0, "cached"))
        else:
            if go is None and name != "node-runtime":
                go = GoToolchain.find(v)
            tool.root.mkdir(parents=True, exist_ok=True)
            blog = tool.root / "build.log"
            blog.write_text("")
            log(f"{name}: building into {tool.root} (log: {blog})")
            BUILDERS[name](tool, v, go, blog)
            bad = [str(b) for b, a, e in tool.checks if not _version_ok(b, a, e)]
            if bad:
                raise HarnessError(f"{name}: built, but the --version check failed for {bad}")
            tool.stamp_built()
            if not tool.ok():
                raise HarnessError(f"{name}: built, but a file it makes is missing")
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
