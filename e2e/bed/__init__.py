"""The local Kubernetes control plane for e2e tests and benchmarks (see harness.py).

from e2e.bed import ensure_up
cluster = ensure_up()          # starts it if needed; idempotent
cluster.kubeconfig, cluster.prometheus_url, cluster.add_prometheus_target("twin", "127.0.0.1:9123")
cluster.in_cluster_prometheus_url   # what pods use: http://prometheus.monitoring.svc:9090
cluster.dns_service_ip              # kube-system/kube-dns (CoreDNS), the pods' nameserver
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
