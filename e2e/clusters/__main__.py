"""``python -m e2e.clusters kind|k3d [--keep] [pytest args...]`` (make e2e-kind, make e2e-k3d).

Checks Docker first (``docker.check``: refuses with the reason, exit 2, nothing created), then
creates the cluster from ``layout``, builds the operator and workload images with Docker from
the repository's Dockerfiles, loads them into the nodes, and runs the portable suite
(``pytest e2e/tests --with-e2e`` against the cluster's kubeconfig: the rest is deselected). The
cluster is deleted afterwards unless ``--keep``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from e2e.bed.base import CACHE_ROOT, REPO_ROOT
from e2e.clusters import docker, layout
from e2e.portable.settings import MODULE_IMAGE, OPERATOR_IMAGE

IMAGES = (
    (OPERATOR_IMAGE, "Dockerfile"),
    (MODULE_IMAGE, "workloads/ros2-module/Dockerfile"),
)


@dataclass(frozen=True)
class Provider:
    """The commands of one tool for a cluster ``name`` whose config is at ``config``."""

    tool: str
    name: str
    config: Path

    def document(self, image: str) -> dict[str, object]:
        make = layout.kind_config if self.tool == "kind" else layout.k3d_config
        return make(image, self.name)

    def create(self) -> list[str]:
        if self.tool == "kind":
            return ["kind", "create", "cluster", "--config", str(self.config), "--wait", "300s"]
        return ["k3d", "cluster", "create", "--config", str(self.config)]

    def kubeconfig(self) -> list[str]:
        if self.tool == "kind":
            return ["kind", "get", "kubeconfig", "--name", self.name]
        return ["k3d", "kubeconfig", "get", self.name]

    def load(self, image: str) -> list[str]:
        if self.tool == "kind":
            return ["kind", "load", "docker-image", image, "--name", self.name]
        return ["k3d", "image", "import", image, "--cluster", self.name]

    def delete(self) -> list[str]:
        if self.tool == "kind":
            return ["kind", "delete", "cluster", "--name", self.name]
        return ["k3d", "cluster", "delete", self.name]


def _step(cmd: list[str], **kw: object) -> subprocess.CompletedProcess[str]:
    print("+ " + " ".join(cmd), flush=True)
    return subprocess.run(cmd, check=True, text=True, **kw)  # type: ignore[call-overload]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m e2e.clusters", description=__doc__)
    parser.add_argument("tool", choices=("kind", "k3d"))
    parser.add_argument("--keep", action="store_true", help="keep the cluster afterwards")
    parser.add_argument("--name", default=layout.CLUSTER)
    args, pytest_args = parser.parse_known_args(argv)
    image = layout.node_image(args.tool)
    try:
        docker.check(args.tool, image)
    except docker.Refused as exc:
        print(exc, file=sys.stderr)
        return 2
    state = CACHE_ROOT / args.tool
    state.mkdir(parents=True, exist_ok=True)
    provider = Provider(args.tool, args.name, state / "cluster.json")
    provider.config.write_text(json.dumps(provider.document(image), indent=1))  # YAML reads JSON
    kubeconfig = state / "kubeconfig"
    try:
        _step(provider.create())
        out = _step(provider.kubeconfig(), capture_output=True).stdout
        kubeconfig.write_text(out)
        kubeconfig.chmod(0o600)
        for ref, dockerfile in IMAGES:
            _step(["docker", "build", "-t", ref, "-f", str(REPO_ROOT / dockerfile), str(REPO_ROOT)])
            _step(provider.load(ref))
        env = {**os.environ, "FOGFLEET_E2E_EXTERNAL": "1",
               "FOGFLEET_E2E_KUBECONFIG": str(kubeconfig)}  # fmt: skip
        pytest = [sys.executable, "-m", "pytest", str(REPO_ROOT / "e2e" / "tests"), "--with-e2e"]
        return subprocess.run([*pytest, "-q", *pytest_args], env=env, check=False).returncode
    except subprocess.CalledProcessError as exc:
        print(f"make e2e-{args.tool}: {' '.join(exc.cmd)} exited {exc.returncode}", file=sys.stderr)
        return 1
    finally:
        if args.keep:
            print(f"kept {args.tool} cluster {args.name} (kubeconfig {kubeconfig})")
        else:
            subprocess.run(provider.delete(), check=False)


if __name__ == "__main__":
    sys.exit(main())
