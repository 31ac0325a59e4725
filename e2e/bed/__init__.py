"""The local Kubernetes control plane for e2e tests and benchmarks (see harness.py).

from e2e.bed import ensure_up
cluster = ensure_up()          # starts it if needed; idempotent
cluster.kubeconfig, cluster.prometheus_url, cluster.add_prometheus_target("twin", "127.0.0.1:9123")
"""

from e2e.bed.harness import (
    BIN_DIR,
    CACHE_ROOT,
    KUBECONFIG,
    PROMETHEUS_TARGETS_DIR,
    STATE_DIR,
    Cluster,
    HarnessError,
    create_nodes,
    down,
    ensure_built,
    ensure_up,
    running,
)

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
