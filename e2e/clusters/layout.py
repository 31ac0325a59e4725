"""The Docker-based test clusters' nodes and the kind and k3d configurations that make them.

Two robots and an edge node, labelled as docs/development.md asks (``fogfleet.io/tier``,
``fogfleet.io/hardware-type``, ``fogfleet.io/robot``); the control plane / server carries no
fogfleet label, so the suite plans nothing onto it. The API server listens on 127.0.0.1 only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from e2e.bed.base import load_versions

__all__ = ["API_PORT", "CLUSTER", "WORKERS", "Worker", "k3d_config", "kind_config", "node_image"]

CLUSTER = "fogfleet-e2e"
API_PORT = 16550


@dataclass(frozen=True)
class Worker:
    tier: str
    hardware: str
    robot: str | None = None

    @property
    def labels(self) -> dict[str, str]:
        out = {"fogfleet.io/tier": self.tier, "fogfleet.io/hardware-type": self.hardware}
        if self.robot:
            out["fogfleet.io/robot"] = self.robot
        return out


WORKERS = (
    Worker("robot", "robot-nuc", "robot-1"),
    Worker("robot", "robot-nuc", "robot-2"),
    Worker("edge", "edge-server"),
)


def node_image(provider: str, versions: dict[str, str] | None = None) -> str:
    """The node image pinned in e2e/bed/versions.env (KIND_NODE_IMAGE, K3S_IMAGE)."""
    versions = load_versions() if versions is None else versions
    return versions[{"kind": "KIND_NODE_IMAGE", "k3d": "K3S_IMAGE"}[provider]]


def kind_config(image: str, name: str = CLUSTER, api_port: int = API_PORT) -> dict[str, Any]:
    """A kind Cluster (kind.x-k8s.io/v1alpha4): a control plane and one worker per WORKERS."""
    return {
        "kind": "Cluster",
        "apiVersion": "kind.x-k8s.io/v1alpha4",
        "name": name,
        "networking": {"apiServerAddress": "127.0.0.1", "apiServerPort": api_port},
        "nodes": [
            {"role": "control-plane", "image": image},
            *({"role": "worker", "image": image, "labels": w.labels} for w in WORKERS),
        ],
    }


def k3d_config(image: str, name: str = CLUSTER, api_port: int = API_PORT) -> dict[str, Any]:
    """A k3d Simple config (k3d.io/v1alpha5): one server, agent i labelled as WORKERS[i]."""
    labels = [
        {"label": f"{key}={value}", "nodeFilters": [f"agent:{i}"]}
        for i, worker in enumerate(WORKERS)
        for key, value in worker.labels.items()
    ]
    return {
        "apiVersion": "k3d.io/v1alpha5",
        "kind": "Simple",
        "metadata": {"name": name},
        "servers": 1,
        "agents": len(WORKERS),
        "image": image,
        "kubeAPI": {"hostIP": "127.0.0.1", "hostPort": str(api_port)},
        "options": {
            "k3d": {"wait": True, "timeout": "300s", "disableLoadbalancer": True},
            "k3s": {
                "extraArgs": [
                    {"arg": "--disable=traefik", "nodeFilters": ["server:*"]},
                    {"arg": "--disable=servicelb", "nodeFilters": ["server:*"]},
                ],
                "nodeLabels": labels,
            },
            "kubeconfig": {"updateDefaultKubeconfig": False, "switchCurrentContext": False},
        },
    }
