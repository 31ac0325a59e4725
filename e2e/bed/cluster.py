"""The Python API of a running bed: :class:`Cluster` (kubectl, Prometheus, node chaos)."""

from __future__ import annotations

import json
import re
import ssl
import subprocess
import time
import urllib.error
import urllib.parse
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from e2e.bed.base import (
    BIN_DIR,
    HOST,
    KUBECONFIG,
    PROMETHEUS_TARGETS_DIR,
    STATE_DIR,
    HarnessError,
    http_get,
    insecure_tls,
)
from e2e.bed.base import kubectl as run_kubectl
from e2e.bed.bednet import DNS_SERVICE_IP
from e2e.bed.clusterservices import COREDNS, IN_CLUSTER_PROMETHEUS_URL
from e2e.bed.processes import _alive, log_tail

COMPONENTS = (
    "etcd",
    "kube-apiserver",
    "kube-controller-manager",
    "kube-scheduler",
    "kwok",
    "prometheus",
)
# Preferred ports (a busy one is replaced by a free ephemeral port and recorded in state.json).
PREFERRED_PORTS = {
    "etcd": 23790,
    "etcd-peer": 23800,
    "kube-apiserver": 26443,
    "kube-controller-manager": 26257,
    "kube-scheduler": 26259,
    "kwok": 26250,
    "prometheus": 29090,
    # CoreDNS's health and ready plugins (its DNS port is 53 on the bridge address)
    "coredns-health": 28080,
    "coredns-ready": 28181,
}
# controller marks a node whose Lease is older than the grace period Ready=Unknown and taints it.
NODE_LEASE_SECONDS = 10
NODE_MONITOR_PERIOD = "1s"
# Client rate limits of kube-controller-manager and kube-scheduler. The defaults (20/30 and
# 50/100 requests per second) make the cluster, not fogfleet, the bottleneck at hundreds of
# pods: 400 Deployments' status updates trail their pods by ~25 s at 20/s, and a fleet cannot
# be Ready before its Deployments say so (issue 15). Production control planes raise them too.
CONTROLLER_API_QPS = 200
CONTROLLER_API_BURST = 400
NODE_MONITOR_GRACE_PERIOD = "10s"
# Pods get NoExecute tolerations of this many seconds for not-ready/unreachable nodes (the
# upstream default is 300 s), so evictions from a failed node happen within a test's timeout.
POD_EVICTION_TOLERATION_SECONDS = 10
PROMETHEUS_SCRAPE_INTERVAL = "2s"

# kwok stops managing (heartbeating) a node that carries this label with the value "stopped".
HEARTBEAT_LABEL = "fogfleet.io/e2e-heartbeat"
# kwok's own chaos stage: a node with this label set to "true" reports Ready=False.
KWOK_NOT_READY_LABEL = "node-not-ready.stage.kwok.x-k8s.io"


def condition_status(obj: Mapping[str, Any], type_: str) -> str | None:
    """The status ("True", "False", "Unknown") of an object's condition ``type_``, if it has one."""
    for c in (obj.get("status") or {}).get("conditions") or []:
        if c.get("type") == type_:
            return str(c.get("status"))
    return None


def _read_state() -> dict[str, Any] | None:
    try:
        state: dict[str, Any] = json.loads((STATE_DIR / "state.json").read_text())
    except (OSError, ValueError):
        return None
    return state


def probe(
    url: str, ok: Callable[[str], bool], context: ssl.SSLContext | None = None
) -> tuple[bool, str]:
    """GET ``url``: whether ``ok`` holds of its body, and the body (or why the GET failed)."""
    try:
        body = http_get(url, context=context).strip()
    except (OSError, urllib.error.URLError, ssl.SSLError) as exc:
        return False, str(getattr(exc, "reason", exc))
    return ok(body), body


def is_ok(body: str) -> bool:
    """What a Kubernetes component's /healthz or /readyz answers when it is."""
    return body == "ok"


def _health(name: str, ports: Mapping[str, int]) -> tuple[bool, str]:
    port = ports[name]
    if name == "etcd":
        return probe(f"http://{HOST}:{port}/health", lambda body: '"health":"true"' in body)
    if name == "kube-apiserver":
        ctx = ssl.create_default_context(cafile=str(STATE_DIR / "pki" / "ca.crt"))
        return probe(f"https://{HOST}:{port}/readyz", is_ok, ctx)
    if name in ("kube-controller-manager", "kube-scheduler", "kwok"):
        return probe(f"https://{HOST}:{port}/healthz", is_ok, insecure_tls())
    if name == "prometheus":
        return probe(f"http://{HOST}:{port}/-/ready", lambda body: "Ready" in body)
    raise HarnessError(f"unknown component {name}")


@dataclass(frozen=True)
class Cluster:
    """A running local control plane. Everything listens on 127.0.0.1."""

    state_dir: Path
    bin_dir: Path
    kubeconfig: Path
    api_server: str
    prometheus_url: str
    prometheus_targets_dir: Path
    ports: Mapping[str, int]
    real_nodes: tuple[str, ...] = ()
    versions: Mapping[str, str] = field(default_factory=dict)
    profile: str = "default"  # the bed profile (realnodes.PROFILES) it was started with

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> Cluster:
        ports = dict(state["ports"])
        return cls(
            real_nodes=tuple(state.get("real_nodes", ())),
            versions=dict(state.get("versions", {})),
            profile=str(state.get("profile", "default")),
            state_dir=STATE_DIR,
            bin_dir=BIN_DIR,
            kubeconfig=KUBECONFIG,
            api_server=f"https://{HOST}:{ports['kube-apiserver']}",
            prometheus_url=f"http://{HOST}:{ports['prometheus']}",
            prometheus_targets_dir=PROMETHEUS_TARGETS_DIR,
            ports=ports,
        )

    @property
    def in_cluster_prometheus_url(self) -> str:
        """Where pods reach the bed's Prometheus (Service monitoring/prometheus, by name through
        cluster DNS), as they reach a user's; empty on a bed without real nodes."""
        return IN_CLUSTER_PROMETHEUS_URL if self.real_nodes else ""

    @property
    def dns_service_ip(self) -> str:
        """The cluster DNS Service's address (kube-system/kube-dns: CoreDNS), which the real
        nodes' kubelets give their pods; empty on a bed without real nodes."""
        return DNS_SERVICE_IP if self.real_nodes else ""

    @property
    def logs_dir(self) -> Path:
        return self.state_dir / "logs"

    def health(self) -> dict[str, tuple[bool, str]]:
        return {c: _health(c, self.ports) for c in COMPONENTS}

    def kubectl(
        self, *args: str, input: str | None = None, check: bool = True, timeout: float = 120
    ) -> subprocess.CompletedProcess[str]:
        """Run the harness's kubectl against this cluster (:func:`e2e.bed.base.kubectl`)."""
        return run_kubectl(
            self.bin_dir / "kubectl", self.kubeconfig, *args,
            input=input, check=check, timeout=timeout,
        )  # fmt: skip

    def kubectl_json(self, *args: str) -> Any:
        return json.loads(self.kubectl(*args, "-o", "json").stdout)

    def add_prometheus_target(
        self, name: str, address: str, labels: Mapping[str, str] | None = None
    ) -> Path:
        """Make Prometheus scrape http://<address>/metrics (job=<name>) within a few seconds.

        Only loopback addresses are accepted: nothing on this network may be scraped.
        """
        host = address.rsplit(":", 1)[0]
        if host not in (HOST, "localhost"):
            raise HarnessError(f"refusing scrape target {address!r}: only {HOST} is allowed")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            raise HarnessError(f"bad target name {name!r}")
        self.prometheus_targets_dir.mkdir(parents=True, exist_ok=True)
        group = [{"targets": [address], "labels": {"job": name, **(labels or {})}}]
        path = self.prometheus_targets_dir / f"{name}.json"
        tmp = self.prometheus_targets_dir / f".{name}.tmp"
        tmp.write_text(json.dumps(group, indent=1) + "\n")
        tmp.replace(path)  # atomic: Prometheus never reads a half-written file
        return path

    def remove_prometheus_target(self, name: str) -> None:
        (self.prometheus_targets_dir / f"{name}.json").unlink(missing_ok=True)

    def prometheus_query(self, promql: str) -> list[dict[str, Any]]:
        """Instant query; returns the `result` vector (raises on a Prometheus error)."""
        url = f"{self.prometheus_url}/api/v1/query?" + urllib.parse.urlencode({"query": promql})
        body = json.loads(http_get(url, timeout=10))
        if body.get("status") != "success":
            raise HarnessError(f"Prometheus query {promql!r} failed: {body}")
        result: list[dict[str, Any]] = body["data"]["result"]
        return result

    def set_node_not_ready(self, node: str, not_ready: bool = True) -> None:
        """kwok's chaos stage: the node reports Ready=False (kubelet says "not ready").

        The Lease is still renewed; the node-lifecycle controller taints the node
        node.kubernetes.io/not-ready within about a second. `not_ready=False` recovers it.
        """
        value = f"{KWOK_NOT_READY_LABEL}=true" if not_ready else f"{KWOK_NOT_READY_LABEL}-"
        self.kubectl("label", "node", node, value, "--overwrite")

    def stop_node_heartbeat(self, node: str) -> None:
        """kwok stops managing the node (no Lease renewals, no status): a lost node.

        After NODE_MONITOR_GRACE_PERIOD the node-lifecycle controller sets Ready=Unknown and
        taints it node.kubernetes.io/unreachable (NoSchedule + NoExecute).
        """
        self.kubectl("label", "node", node, f"{HEARTBEAT_LABEL}=stopped", "--overwrite")

    def resume_node_heartbeat(self, node: str) -> None:
        self.kubectl("label", "node", node, f"{HEARTBEAT_LABEL}-")

    def set_link(self, node: str, **change: float) -> None:
        """Change a real node's emulated link while the bed runs (delay_ms, jitter_ms,
        rate_mbit, loss_percent; unnamed fields keep nodes.yaml's values). loss 100 cuts it."""
        from e2e.bed import realnodes

        realnodes.set_link(self._real(node), **change)

    def reset_link(self, node: str) -> None:
        """Back to the link nodes.yaml declares for the node."""
        from e2e.bed import realnodes

        realnodes.set_link(self._real(node))

    def _real(self, name: str) -> Any:
        from e2e.bed import realnodes

        if name not in self.real_nodes:
            raise HarnessError(f"{name} is not a real node of this bed ({self.real_nodes})")
        return realnodes.declared(name)

    def ready_fake_pods_again(self, namespace: str) -> list[str]:
        """Do for kwok's fake pods what a kubelet does after its node was unreachable.

        When a node's Lease is late (an API server down for longer than the bed's 10 s node
        grace period), kube-controller-manager marks the node's pods Ready=False. A kubelet
        reports its running pods Ready again once it reaches the API server; kwok does not
        (its pod stage fired once), so its pods would stay unready for ever. This sets
        Ready=True on the Running pods of ``namespace`` on fake nodes that are Ready again
        and whose containers are ready; returns the pods it changed."""
        nodes = self.kubectl_json("get", "nodes")["items"]
        fake_ready = {
            n["metadata"]["name"]
            for n in nodes
            if (n["metadata"].get("annotations") or {}).get("kwok.x-k8s.io/node") == "fake"
            and condition_status(n, "Ready") == "True"
        }
        changed = []
        for pod in self.kubectl_json("get", "pods", "-n", namespace)["items"]:
            if (
                pod["spec"].get("nodeName") in fake_ready
                and not pod["metadata"].get("deletionTimestamp")
                and pod["status"].get("phase") == "Running"
                and condition_status(pod, "ContainersReady") == "True"
                and condition_status(pod, "Ready") == "False"
            ):
                now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
                ready = {"type": "Ready", "status": "True", "lastTransitionTime": now}
                patch = json.dumps({"status": {"conditions": [ready]}})
                name = pod["metadata"]["name"]
                self.kubectl("patch", "pod", name, "-n", namespace, "--subresource=status",
                             "--type=strategic", "-p", patch)  # fmt: skip
                changed.append(name)
        return changed

    def log_tail(self, component: str, lines: int = 40) -> str:
        return log_tail(component, lines)


def running() -> Cluster | None:
    """The running cluster if every component is healthy, else None (never starts anything)."""
    state = _read_state()
    if state is None or state.get("phase") != "running":
        return None
    cluster = Cluster.from_state(state)
    real = [f"node-{n}" for n in state.get("real_nodes", [])]
    gateway = ["bed-gateway", COREDNS] if real else []
    if not all(_alive(c) for c in (*COMPONENTS, *real, *gateway)):
        return None
    if all(ok for ok, _ in cluster.health().values()):
        return cluster
    return None
