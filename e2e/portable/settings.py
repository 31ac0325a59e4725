"""What the portable run reads from its environment: the only reader of ``os.environ`` here.

Every value has a default that works on a cluster where the repository's images are already
loaded into the nodes' runtimes under their release tags (the bed, ``make e2e-kind``,
``make e2e-k3d``); a cluster that pulls from a registry sets the image refs and the policy.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ENV_HELM", "ENV_MODULE_IMAGE", "ENV_OPERATOR_IMAGE", "ENV_PULL_POLICY", "Settings"]

ENV_HELM = "FOGFLEET_E2E_HELM"
ENV_OPERATOR_IMAGE = "FOGFLEET_E2E_OPERATOR_IMAGE"
ENV_MODULE_IMAGE = "FOGFLEET_E2E_MODULE_IMAGE"
ENV_PULL_POLICY = "FOGFLEET_E2E_PULL_POLICY"

OPERATOR_IMAGE = "ghcr.io/fogfleet/fogfleet:0.1.0"
MODULE_IMAGE = "ghcr.io/fogfleet/ros2-module:0.1.0"
PULL_POLICIES = ("IfNotPresent", "Never", "Always")


@dataclass(frozen=True)
class Settings:
    helm: str
    operator_image: str
    module_image: str
    pull_policy: str

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None) -> Settings:
        env = dict(os.environ if env is None else env)
        cache = Path(env.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fogfleet"
        built = cache / "bin" / "helm"  # the bed's, when it was built here (make cluster-tools)
        helm = env.get(ENV_HELM) or (str(built) if built.exists() else None)
        helm = helm or shutil.which("helm", path=env.get("PATH", "")) or ""
        if not helm or not Path(helm).exists():
            raise ValueError(f"no helm: set {ENV_HELM} or put helm on PATH")
        policy = env.get(ENV_PULL_POLICY) or "IfNotPresent"
        if policy not in PULL_POLICIES:
            raise ValueError(f"{ENV_PULL_POLICY}={policy}: one of {', '.join(PULL_POLICIES)}")
        return cls(
            helm=helm,
            operator_image=env.get(ENV_OPERATOR_IMAGE) or OPERATOR_IMAGE,
            module_image=env.get(ENV_MODULE_IMAGE) or MODULE_IMAGE,
            pull_policy=policy,
        )


def split_image(ref: str) -> tuple[str, str]:
    """``repo[:tag]`` -> (repo, tag); a registry port is not a tag; a digest is refused."""
    if "@" in ref:
        raise ValueError(f"{ref}: give a tag, not a digest (the chart takes repository + tag)")
    repo, sep, tag = ref.rpartition(":")
    if not sep or "/" in tag:
        return ref, "latest"
    return repo, tag
