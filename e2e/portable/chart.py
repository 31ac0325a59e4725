"""The operator installed in-cluster by ``charts/fogfleet``, as a user would (``helm install``).

Helm runs with the suite's kubeconfig and a private HELM_*_HOME, so the user's repositories and
releases elsewhere are neither read nor written. The release has its own name and namespace and
watches only the test's namespace, so it never competes with another operator on the cluster.
"""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from e2e.portable.settings import split_image

__all__ = ["CHART", "NAMESPACE", "RELEASE", "Helm", "install_args"]

CHART = Path(__file__).resolve().parents[2] / "charts" / "fogfleet"
RELEASE = "fogfleet-portable"
NAMESPACE = "fogfleet-portable"


def _escape(key: str) -> str:
    return key.replace(".", "\\.")


def install_args(
    watch: str, image: str, pull_policy: str, node_selector: dict[str, str]
) -> list[str]:
    """``helm install`` arguments: one replica (nothing here tests failover; it leaves room on a
    small edge node), the given image, watching ``watch`` only, pinned by ``node_selector``.
    The suite applies the CRDs itself (``kubectl apply``): another release may own them, and
    this one must neither take them over nor keep them after it is gone."""
    repo, tag = split_image(image)
    args = [
        "install", RELEASE, str(CHART), "-n", NAMESPACE, "--create-namespace",
        "--set", f"watchNamespaces={{{watch}}}",
        "--set", "crds.install=false",
        "--set", "replicaCount=1",
        "--set", "resources.requests.cpu=100m",
        "--set", "logFormat=plain",
        "--set", f"image.repository={repo}",
        "--set-string", f"image.tag={tag}",
        "--set", f"image.pullPolicy={pull_policy}",
        "--wait", "--timeout", "240s",
    ]  # fmt: skip
    for key, value in sorted(node_selector.items()):
        args += ["--set-string", f"nodeSelector.{_escape(key)}={value}"]
    return args


@dataclass(frozen=True)
class Helm:
    binary: str
    kubeconfig: Path
    home: Path

    def __call__(self, *args: str, timeout: float = 300) -> str:
        env = {
            **os.environ,
            "KUBECONFIG": str(self.kubeconfig),
            "HELM_CACHE_HOME": str(self.home / "cache"),
            "HELM_CONFIG_HOME": str(self.home / "config"),
            "HELM_DATA_HOME": str(self.home / "data"),
        }
        proc = subprocess.run(
            [self.binary, "--kubeconfig", str(self.kubeconfig), *args],
            capture_output=True, text=True, timeout=timeout, check=False, env=env,
        )  # fmt: skip
        if proc.returncode != 0:
            raise AssertionError(f"helm {' '.join(args)}:\n{proc.stdout}\n{proc.stderr}")
        return proc.stdout

    def uninstall(self) -> None:
        if RELEASE in self("list", "-n", NAMESPACE, "-q").split():
            self("uninstall", RELEASE, "-n", NAMESPACE, "--wait")
