"""Guarded access to the cluster the e2e tests run on (used by e2e/tests/conftest.py).

`Kube` is what tests talk through: kubectl with the guarded kubeconfig, apply, a
kubernetes.client.ApiClient, token kubeconfigs for RBAC tests. `guard_kubeconfig` refuses any
kubeconfig that is not the harness's own 127.0.0.1 API server (or, for an external cluster, the
one file named explicitly).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from e2e.bed import harness
from e2e.bed.base import PROGRESS_SECONDS
from e2e.bed.base import kubectl as run_kubectl

__all__ = ["Kube", "UnsafeKubeconfig", "guard_kubeconfig"]


class UnsafeKubeconfig(Exception):
    """The kubeconfig could point at a cluster that is not ours to create and delete things in."""


def _current_server(config: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    contexts = {c["name"]: c["context"] for c in config.get("contexts") or []}
    clusters = {c["name"]: c["cluster"] for c in config.get("clusters") or []}
    ctx = contexts.get(config.get("current-context", ""))
    if ctx is None or ctx.get("cluster") not in clusters:
        raise UnsafeKubeconfig("kubeconfig has no usable current-context")
    cluster = clusters[ctx["cluster"]]
    return str(cluster["server"]), cluster


def guard_kubeconfig(path: Path, *, expected_server: str | None) -> str:
    """Return the kubeconfig's API server, or raise if it is not the one the tests may use.

    `expected_server` None means external mode: the caller named this file explicitly.
    """
    if not path.is_file():
        raise UnsafeKubeconfig(f"kubeconfig {path} does not exist")
    config = yaml.safe_load(path.read_text()) or {}
    server, _ = _current_server(config)
    servers = {str(c["cluster"]["server"]) for c in config.get("clusters") or []}
    if len(servers) != 1:
        raise UnsafeKubeconfig(
            f"{path} names {len(servers)} API servers ({sorted(servers)}); the e2e tests "
            "accept a kubeconfig with exactly one cluster"
        )
    if expected_server is not None:
        host = urllib.parse.urlsplit(server).hostname
        if path.resolve() != harness.KUBECONFIG.resolve():
            raise UnsafeKubeconfig(f"{path} is not the harness kubeconfig {harness.KUBECONFIG}")
        if server != expected_server or host != "127.0.0.1":
            raise UnsafeKubeconfig(
                f"refusing kubeconfig {path}: server {server} is not the harness's own "
                f"API server {expected_server}"
            )
    return server


@dataclass(frozen=True)
class Kube:
    kubeconfig: Path
    server: str
    kubectl_bin: str
    external: bool
    cluster: harness.Cluster | None

    def kubectl(
        self,
        *args: str,
        input: str | None = None,
        check: bool = True,
        timeout: float = 120,
        kubeconfig: Path | None = None,
    ) -> subprocess.CompletedProcess[str]:
        """kubectl with the guarded kubeconfig (or another one for the same server, e.g. a
        ServiceAccount token kubeconfig written by a test)."""
        config = kubeconfig or self.kubeconfig
        if kubeconfig is not None:
            other = yaml.safe_load(kubeconfig.read_text())
            if _current_server(other)[0] != self.server:
                raise UnsafeKubeconfig(f"{kubeconfig} does not point at {self.server}")
        return run_kubectl(
            self.kubectl_bin, config, *args,
            input=input, check=check, timeout=timeout, error=AssertionError,
        )  # fmt: skip

    def kubectl_json(self, *args: str) -> Any:
        return json.loads(self.kubectl(*args, "-o", "json").stdout)

    def create_namespace(self, name: str, labels: dict[str, str] | None = None) -> None:
        """Namespace ``name`` (with ``labels``), once its ``default`` ServiceAccount exists:
        pods created before it are refused."""
        meta: dict[str, Any] = {"name": name} | ({"labels": labels} if labels else {})
        self.apply({"apiVersion": "v1", "kind": "Namespace", "metadata": meta})
        self.wait_for(
            f"ServiceAccount default in {name}",
            lambda: self.kubectl("get", "sa", "default", "-n", name, check=False).returncode == 0,
            timeout=60,
            interval=0.3,
        )

    def apply(
        self, manifest: str | dict[str, Any] | list[dict[str, Any]], namespace: str | None = None
    ) -> str:
        """kubectl apply a YAML string, an object or a list of objects; returns kubectl's output."""
        if isinstance(manifest, dict):
            manifest = json.dumps(manifest)
        elif isinstance(manifest, list):
            manifest = json.dumps({"apiVersion": "v1", "kind": "List", "items": manifest})
        ns = [f"--namespace={namespace}"] if namespace else []
        return self.kubectl("apply", *ns, "-f", "-", input=manifest).stdout

    def token_kubeconfig(self, token: str, path: Path) -> Path:
        """A kubeconfig for the same API server that authenticates with a bearer token."""
        config = yaml.safe_load(self.kubeconfig.read_text())
        _, cluster = _current_server(config)
        path.write_text(
            json.dumps(
                {
                    "apiVersion": "v1",
                    "kind": "Config",
                    "clusters": [{"name": "e2e", "cluster": cluster}],
                    "users": [{"name": "token", "user": {"token": token}}],
                    "contexts": [{"name": "token", "context": {"cluster": "e2e", "user": "token"}}],
                    "current-context": "token",
                }
            )
        )
        path.chmod(0o600)
        return path

    def api_client(self, kubeconfig: Path | None = None) -> Any:
        """A kubernetes.client.ApiClient for this cluster (the official Python client)."""
        from kubernetes import config as kube_config

        return kube_config.new_client_from_config(  # type: ignore[no-untyped-call]
            config_file=str(kubeconfig or self.kubeconfig)
        )

    def wait_for(
        self, what: str, check: Callable[[], bool], timeout: float = 60, interval: float = 0.5
    ) -> None:
        """Poll until ``check`` holds. A wait past ``PROGRESS_SECONDS`` says so on the terminal
        (``sys.__stderr__``: pytest captures the test's own output), so a long e2e test is
        never silent for long."""
        t0 = time.monotonic()
        deadline, report = t0 + timeout, t0 + PROGRESS_SECONDS
        while not check():
            now = time.monotonic()
            if now > deadline:
                raise AssertionError(f"timed out after {timeout:.0f}s waiting for {what}")
            if now > report and sys.__stderr__ is not None:
                print(f"\n    ... waiting for {what}: {now - t0:.0f}s of at most {timeout:.0f}s",
                      end="", file=sys.__stderr__, flush=True)  # fmt: skip
                report = now + PROGRESS_SECONDS
            time.sleep(interval)
