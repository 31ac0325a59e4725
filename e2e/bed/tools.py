"""Build (or reuse from the cache) every pinned tool of the local cluster.

Each tool is built from published Go modules (k8s.io/kubernetes through a wrapper module whose
``replace`` lines are generated from k8s's own go.mod, kwok, etcd, helm, kube-router, Prometheus
with only its kubernetes_sd, CoreDNS through a wrapper main package with only the plugins the
bed uses) into ``TOOLS_DIR/<tool>-<version>/`` and reused after a ``--version`` check. Only the
real nodes' runtime comes from Debian packages. ``GOTOOLCHAIN=local`` always: a too-old Go fails
at once.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

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

TOOLS = ("k8s", "etcd", "kwok", "helm", "prometheus", "coredns", "node-runtime", "kube-router")
# Debian packages a real node runs on (the kubelet and kube-proxy come from the k8s build).
# ipset: kube-router's NetworkPolicy firewall keeps each policy's peers in ip sets.
NODE_PACKAGES = ("containerd", "runc", "containernetworking-plugins", "iptables", "ipset")
# Of Prometheus's service discoveries only kubernetes_sd (plugins/plugin_*.go honour the tags).
PROMETHEUS_TAGS = "remove_all_sd,enable_kubernetes_sd"
K8S_COMMANDS = (
    "kube-apiserver",
    "kube-controller-manager",
    "kube-scheduler",
    "kubelet",
    "kube-proxy",
    "kubectl",
)

# Node health timing. kwok renews each node Lease every lease/4 seconds; the node-lifecycle
KWOK_STAGES = (
    "stage/node/fast/node-initialize.yaml",
    "stage/node/heartbeat-with-lease/node-heartbeat-with-lease.yaml",
    "stage/node/chaos/node-not-ready.yaml",
    "stage/pod/fast/pod-ready.yaml",
    "stage/pod/fast/pod-complete.yaml",
    "stage/pod/fast/pod-delete.yaml",
)


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
    files: list[Path] = field(default_factory=list)

    def ok(self) -> bool:
        return (
            all(_version_ok(b, a, e) for b, a, e in self.checks)
            and all(p.exists() for p in self.extra.values())
            and all(p.exists() for p in self.files)
        )


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
    return {
        "k8s": k8s,
        "etcd": etcd,
        "kwok": kwok,
        "helm": helm,
        "prometheus": prom,
        "coredns": coredns,
        "node-runtime": runtime,
        "kube-router": kube_router,
    }


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
        "-v",  # each package as it is compiled: the log and the progress lines name it
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
        "-v",  # each package as it is compiled: the log and the progress lines name it
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
        "-v",
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


def _go_install(
    go: GoToolchain,
    tool: Tool,
    blog: Path,
    ldflags: Sequence[str],
    packages: Sequence[str],
    tags: str = "",
) -> None:
    """``go install`` of ``packages`` (``path@version``) into the tool's bin directory, each
    package named in the log as it compiles."""
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    go(
        "install",
        "-v",
        "-trimpath",
        *(["-tags", tags] if tags else []),
        "-ldflags",
        " ".join(ldflags),
        *packages,
        log_file=blog,
        extra_env={"GOBIN": str(tool.root / "bin")},
    )


def _build_helm(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    hv, kv = v["HELM_VERSION"], v["K8S_VERSION"]
    major, minor = kv.split(".")[:2]
    ldflags = ["-s", "-w", f"-X helm.sh/helm/v3/internal/version.version=v{hv}"]
    for pkg in ("helm.sh/helm/v3/pkg/chartutil", "helm.sh/helm/v3/pkg/lint/rules"):
        ldflags += [f"-X {pkg}.k8sVersionMajor={major}", f"-X {pkg}.k8sVersionMinor={minor}"]
    _go_install(go, tool, blog, ldflags, [f"helm.sh/helm/v3/cmd/helm@v{hv}"])


def prometheus_module_version(version: str) -> str:
    """Prometheus 3.16.0 is the Go module version v0.316.0 (v0.<MAJOR><MINOR>.<PATCH>)."""
    major, minor, patch = (int(x) for x in version.split("."))
    return f"v0.{major}{minor:02d}.{patch}"


def _build_prometheus(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """``go install`` of cmd/prometheus and cmd/promtool at the pinned module version (its go.mod
    has no ``replace`` lines), with only kubernetes_sd of the service discoveries (the
    ``plugins/plugin_*.go`` files honour the tags). The web UI's assets are not in the module
    (they come from an npm build): the API, which is all the bed and the operator use, works."""
    pv = v["PROMETHEUS_VERSION"]
    module = "github.com/prometheus/prometheus"
    ldflags = ["-s", "-w"]
    for key, value in (("Version", pv), ("Revision", prometheus_module_version(pv)),
                       ("Branch", "go-module-build")):  # fmt: skip
        ldflags.append(f"-X github.com/prometheus/common/version.{key}={value}")
    packages = [
        f"{module}/cmd/{c}@{prometheus_module_version(pv)}" for c in ("prometheus", "promtool")
    ]
    _go_install(go, tool, blog, ldflags, packages, tags=PROMETHEUS_TAGS)


# The bed's CoreDNS: upstream's main package (coredns.go) blank-imports every plugin through
# core/plugin; this one imports only these and sets the directive list to them, in upstream's
# order (core/dnsserver/zdirectives.go). No forward: a name outside cluster.local is REFUSED.
COREDNS_PLUGINS = ("bind", "ready", "health", "errors", "log", "cache", "kubernetes")
_COREDNS_MAIN = """// The fogfleet bed's CoreDNS: only the plugins it uses (e2e/bed/tools.py).
package main

import (
	"github.com/coredns/coredns/core/dnsserver"
	"github.com/coredns/coredns/coremain"
{imports}
)

func init() {{
	dnsserver.Directives = []string{{{directives}}}
}}

func main() {{ coremain.Run() }}
"""


def coredns_main() -> str:
    imports = "\n".join(f'\t_ "github.com/coredns/coredns/plugin/{p}"' for p in COREDNS_PLUGINS)
    return _COREDNS_MAIN.format(
        imports=imports, directives=", ".join(f'"{p}"' for p in COREDNS_PLUGINS)
    )


def _build_coredns(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """A wrapper module whose main package is ``coredns_main()`` (CoreDNS's documented way to
    build with a chosen plugin set, without editing plugin.cfg in a checkout)."""
    src = tool.root / "src"
    src.mkdir(parents=True, exist_ok=True)
    if not (src / "go.mod").exists():
        go("mod", "init", "e2e.local/corednsbin", cwd=src, log_file=blog)
    go("mod", "edit", f"-go={v['GO_MIN_VERSION']}", cwd=src, log_file=blog)
    (src / "main.go").write_text(coredns_main())
    module = f"github.com/coredns/coredns@v{v['COREDNS_VERSION']}"
    info = json.loads(go("mod", "download", "-json", module, cwd=src))
    if info.get("Error"):
        raise HarnessError(f"go mod download {module}: {info['Error']}")
    # CoreDNS's own go.sum vouches for its dependencies, so the checksum database is asked
    # about CoreDNS alone (checksums stay verified; nothing turns verification off).
    upstream = (Path(info["Dir"]) / "go.sum").read_text().splitlines()
    ours = (src / "go.sum").read_text().splitlines() if (src / "go.sum").exists() else []
    (src / "go.sum").write_text("".join(f"{line}\n" for line in dict.fromkeys(ours + upstream)))
    go("get", module, cwd=src, log_file=blog)
    go("mod", "tidy", cwd=src, log_file=blog)
    go("build", "-v", "-trimpath", "-ldflags", "-s -w", "-o", str(tool.binaries["coredns"]), ".",
       cwd=src, log_file=blog)  # fmt: skip


def _build_kube_router(tool: Tool, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """kube-router, run by the real nodes only as a NetworkPolicy firewall (realnodes.py)."""
    krv = v["KUBE_ROUTER_VERSION"]
    module = "github.com/cloudnativelabs/kube-router/v2"
    ldflags = ["-s", "-w", f"-X {module}/pkg/version.Version=v{krv}"]
    _go_install(go, tool, blog, ldflags, [f"{module}/cmd/kube-router@v{krv}"])


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
            if go is None and name != "node-runtime":
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
