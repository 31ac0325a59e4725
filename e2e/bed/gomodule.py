"""The Go toolchain, and the bed's one Go module that the cluster's tools are built from.

Built apart, each tool compiled its own copy of what they share: the Kubernetes libraries at
four versions (client-go v0.36.1, v0.36.2, v0.36.3, v0.37.1), gRPC, protobuf, OpenTelemetry.
Counted in source bytes, that is twice what the tools need once. One wrapper module that
requires them all (``go get -tool``) gives every shared package one version, so Go's build
cache compiles it once and each tool's ``go build`` (own flags, own tags) links it.

The tools keep their pinned releases; their dependencies are chosen by Go's minimum version
selection over all of them, with two sets of ``replace`` lines:

- every k8s.io staging module at the Kubernetes release's tag: ``k8s.io/kubernetes`` requires
  them at ``v0.0.0`` and maps them to ``./staging``, which Go ignores in a dependency;
- etcd's api and client modules at the etcd server's release: CoreDNS asks for etcd v3.7,
  which etcd server v3.6 does not compile against. The bed's CoreDNS has no etcd plugin
  (``COREDNS_PLUGINS``), so nothing of CoreDNS uses them.

kube-router stays apart (``tools._build_kube_router``): v2.1.0 needs client-go v0.29 and a
Docker client whose ``go-connections`` (v0.5) is older than the others need (v0.8), and it does
not compile against theirs.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from e2e.bed.base import TOOLS_DIR, HarnessError, log, run

__all__ = [
    "COREDNS_PLUGINS",
    "K8S_COMMANDS",
    "MODULE_TOOLS",
    "GoToolchain",
    "coredns_main",
    "ensure_module",
    "module_dir",
    "prometheus_module_version",
    "staging_modules",
]

# The tools built from the module (the others: kube-router apart, the node runtime from Debian).
MODULE_TOOLS = ("k8s", "etcd", "kwok", "helm", "prometheus", "coredns")
K8S_COMMANDS = (
    "kube-apiserver",
    "kube-controller-manager",
    "kube-scheduler",
    "kubelet",
    "kube-proxy",
    "kubectl",
)
ETCD_CLIENT_MODULES = ("go.etcd.io/etcd/api/v3", "go.etcd.io/etcd/client/pkg/v3",
                       "go.etcd.io/etcd/client/v3", "go.etcd.io/etcd/pkg/v3")  # fmt: skip
# Bumped when the recipe below changes, so that a cached module made the old way is remade.
RECIPE = 1
RESOLVED = "resolved"  # written last: the module's go.mod and go.sum are complete


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

    def download(self, module: str, cwd: Path | None = None) -> dict[str, str]:
        """``go mod download -json module@version``: where the module cache holds it."""
        info: dict[str, str] = json.loads(self("mod", "download", "-json", module, cwd=cwd))
        if info.get("Error"):
            raise HarnessError(f"go mod download {module}: {info['Error']}")
        return info


def staging_modules(gomod_text: str) -> list[str]:
    """k8s.io/* modules that k8s.io/kubernetes requires at v0.0.0 (its ./staging replaces)."""
    found = re.findall(r"^\s*(?:require\s+)?(k8s\.io/[\w.\-/]+)\s+v0\.0\.0\s*$", gomod_text, re.M)
    return sorted(set(found))


def prometheus_module_version(version: str) -> str:
    """Prometheus 3.16.0 is the Go module version v0.316.0 (v0.<MAJOR><MINOR>.<PATCH>)."""
    major, minor, patch = (int(x) for x in version.split("."))
    return f"v0.{major}{minor:02d}.{patch}"


# The bed's CoreDNS: upstream's main package (coredns.go) blank-imports every plugin through
# core/plugin; this one imports only these and sets the directive list to them, in upstream's
# order (core/dnsserver/zdirectives.go). No forward: a name outside cluster.local is REFUSED.
COREDNS_PLUGINS = ("bind", "ready", "health", "errors", "log", "cache", "kubernetes")
_COREDNS_MAIN = """// The fogfleet bed's CoreDNS: only the plugins it uses (e2e/bed/gomodule.py).
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


def _tool_packages(v: Mapping[str, str]) -> list[str]:
    """Every main package built from the module, at its pinned release (``go get -tool``)."""
    pv = prometheus_module_version(v["PROMETHEUS_VERSION"])
    return [
        *(f"k8s.io/kubernetes/cmd/{c}@v{v['K8S_VERSION']}" for c in K8S_COMMANDS),
        f"go.etcd.io/etcd/server/v3@v{v['ETCD_VERSION']}",
        f"sigs.k8s.io/kwok/cmd/kwok@v{v['KWOK_VERSION']}",
        f"helm.sh/helm/v3/cmd/helm@v{v['HELM_VERSION']}",
        *(f"github.com/prometheus/prometheus/cmd/{c}@{pv}" for c in ("prometheus", "promtool")),
    ]


def module_dir(v: Mapping[str, str]) -> Path:
    """Where the module for these versions lives: one per set of pinned releases and recipe."""
    keys = ("GO_MIN_VERSION", "K8S_VERSION", "ETCD_VERSION", "KWOK_VERSION", "HELM_VERSION",
            "PROMETHEUS_VERSION", "COREDNS_VERSION")  # fmt: skip
    text = json.dumps([RECIPE, *(v[k] for k in keys)])
    return TOOLS_DIR / f"go-module-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def ensure_module(v: Mapping[str, str], go: GoToolchain, blog: Path) -> Path:
    """The module's directory, made once (it resolves the graph and downloads every module):
    a ``go.mod`` with the tools, the ``replace`` lines above, and CoreDNS's main package in
    ``coredns/``. A directory left half made by a failed run is made again."""
    src = module_dir(v)
    if (src / RESOLVED).exists():
        return src
    shutil.rmtree(src, ignore_errors=True)
    (src / "coredns").mkdir(parents=True)
    log(f"go module: resolving the bed's tools into {src}")
    go("mod", "init", "e2e.local/bedtools", cwd=src, log_file=blog)
    go("mod", "edit", f"-go={v['GO_MIN_VERSION']}", cwd=src, log_file=blog)
    kv, ev = v["K8S_VERSION"], v["ETCD_VERSION"]
    kubernetes = go.download(f"k8s.io/kubernetes@v{kv}", src)
    staging = staging_modules(Path(kubernetes["GoMod"]).read_text())
    if not staging:
        raise HarnessError(f"no staging modules in {kubernetes['GoMod']}; go.mod format changed?")
    staging_version = f"v0.{kv.split('.', 1)[1]}"
    log(f"go module: {len(staging)} k8s staging modules -> {staging_version}, etcd -> v{ev}")
    replaces = [f"-replace={m}={m}@{staging_version}" for m in staging]
    replaces += [f"-replace={m}={m}@v{ev}" for m in ETCD_CLIENT_MODULES]
    go("mod", "edit", *replaces, cwd=src, log_file=blog)
    # CoreDNS's own go.sum vouches for its dependencies, so the checksum database is asked
    # about CoreDNS alone (checksums stay verified; nothing turns verification off).
    coredns = f"github.com/coredns/coredns@v{v['COREDNS_VERSION']}"
    upstream = Path(go.download(coredns, src)["Dir"]) / "go.sum"
    (src / "go.sum").write_text(upstream.read_text())
    (src / "coredns" / "main.go").write_text(coredns_main())
    go("get", "-tool", *_tool_packages(v), cwd=src, log_file=blog)
    go("get", coredns, cwd=src, log_file=blog)
    (src / RESOLVED).write_text("\n".join([*_tool_packages(v), coredns]) + "\n")
    return src
