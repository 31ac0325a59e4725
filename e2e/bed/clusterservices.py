"""What a user's cluster has besides its control plane, on the bed: cluster DNS, and a Prometheus
that finds pods through the Kubernetes API and that pods reach at a Service.

    kube-system/kube-dns   Service 198.19.0.10:53 (udp, tcp) -> EndpointSlice 198.18.0.1:53
                           = CoreDNS, a host process bound to the bridge address only
    monitoring/prometheus  Service :9090 -> EndpointSlice 198.18.0.1:<prometheus port>
                           = the gateway (gateway.py), which relays it to Prometheus on 127.0.0.1

Neither Service has a selector: the harness writes their EndpointSlices, and kube-proxy on the
real nodes routes the ClusterIPs to the bridge, as it routes the ``kubernetes`` Service to the
apiserver. CoreDNS and Prometheus read the API with client certificates of their own
(pki.py: ``system:coredns``, ``system:prometheus``) bound to ClusterRoles that only read what
they need: never the admin certificate.

Prometheus discovers pods with ``kubernetes_sd_configs`` (role pod), one entry per real node
with the field selector ``spec.nodeName=<node>`` (the API server's watch cache indexes pods by
node: cheap at 8000 kwok pods), and keeps only pod IPs of the bed's range as a second guard:
kwok's fake pods have addresses that lead nowhere and are never scraped. The relabelling gives
the labels a user's ``kubernetes-pods`` job gives (``namespace``, ``pod``, ``node``,
``job="kubernetes-pods"``; ``prometheus.io/scrape``, ``/port``, ``/path`` annotations), which the
operator's queries use.

CoreDNS serves ``cluster.local`` only and has no ``forward`` plugin compiled in (tools.py): any
other name is REFUSED, nothing is resolved outside the bed.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.bed.base import HOST, STATE_DIR
from e2e.bed.bednet import BED_RANGE, BRIDGE_IP, DNS_SERVICE_IP
from e2e.bed.pki import kubeconfig

__all__ = [
    "CLUSTER_DOMAIN",
    "COREDNS",
    "COREDNS_USER",
    "IN_CLUSTER_PROMETHEUS_URL",
    "MONITORING_NAMESPACE",
    "PROMETHEUS_USER",
    "RBAC",
    "coredns_argv",
    "corefile",
    "kubernetes_pods_job",
    "service_objects",
]

CLUSTER_DOMAIN = "cluster.local"
MONITORING_NAMESPACE = "monitoring"
PROMETHEUS_SERVICE_PORT = 9090
IN_CLUSTER_PROMETHEUS_URL = (
    f"http://prometheus.{MONITORING_NAMESPACE}.svc:{PROMETHEUS_SERVICE_PORT}"
)
DNS_PORT = 53
COREDNS = "coredns"  # its process name (pid file, log)
PROMETHEUS_USER = "system:prometheus"
COREDNS_USER = "system:coredns"
# The pod IPs Prometheus may scrape: the real nodes' pod ranges inside the bed's 198.18.0.0/15.
BED_POD_IP_REGEX = r"198\.1[89]\.\d+\.\d+"
assert BED_RANGE == "198.18.0.0/15"  # the regex above says the same
SCRAPE_ANNOTATION = "__meta_kubernetes_pod_annotation_prometheus_io_scrape"
PORT_ANNOTATION = "__meta_kubernetes_pod_annotation_prometheus_io_port"
PATH_ANNOTATION = "__meta_kubernetes_pod_annotation_prometheus_io_path"
DEFAULT_METRICS_PORT = "9100"


def _read_role(name: str, rules: list[dict[str, Any]], user: str) -> list[dict[str, Any]]:
    role = f"fogfleet-bed:{name}"
    return [
        {
            "apiVersion": "rbac.authorization.k8s.io/v1",
            "kind": "ClusterRole",
            "metadata": {"name": role},
            "rules": rules,
        },
        {
            "apiVersion": "rbac.authorization.k8s.io/v1",
            "kind": "ClusterRoleBinding",
            "metadata": {"name": role},
            "roleRef": {
                "apiGroup": "rbac.authorization.k8s.io",
                "kind": "ClusterRole",
                "name": role,
            },
            "subjects": [{"apiGroup": "rbac.authorization.k8s.io", "kind": "User", "name": user}],
        },
    ]


_READ = ["get", "list", "watch"]
# kubernetes_sd with role pod lists and watches pods, nothing else (no attach_metadata).
# CoreDNS's kubernetes plugin watches Services, EndpointSlices and Namespaces (`pods disabled`).
RBAC: list[dict[str, Any]] = [
    *_read_role("prometheus", [{"apiGroups": [""], "resources": ["pods"], "verbs": _READ}],
                PROMETHEUS_USER),
    *_read_role(
        "coredns",
        [
            {"apiGroups": [""], "resources": ["services", "namespaces"],
             "verbs": ["list", "watch"]},
            {"apiGroups": ["discovery.k8s.io"], "resources": ["endpointslices"],
             "verbs": ["list", "watch"]},
        ],
        COREDNS_USER,
    ),
]  # fmt: skip


def kubernetes_pods_job(api_server: str, nodes: Sequence[str], pki: Path) -> dict[str, Any]:
    """The ``kubernetes-pods`` scrape job: annotated Running pods of the real nodes."""
    tls = {
        "ca_file": str(pki / "ca.crt"),
        "cert_file": str(pki / "prometheus.crt"),
        "key_file": str(pki / "prometheus.key"),
    }
    sd = [
        {
            "role": "pod",
            "api_server": api_server,
            "tls_config": tls,
            "selectors": [{"role": "pod", "field": f"spec.nodeName={node}"}],
        }
        for node in nodes
    ]
    relabel: list[dict[str, Any]] = [
        {"source_labels": [SCRAPE_ANNOTATION], "regex": "true", "action": "keep"},
        {"source_labels": ["__meta_kubernetes_pod_phase"], "regex": "Running", "action": "keep"},
        {"source_labels": ["__meta_kubernetes_pod_ip"], "regex": BED_POD_IP_REGEX,
         "action": "keep"},
        # the port: the annotation's, else 9100 (one target per pod, whatever its containers)
        {"target_label": "__tmp_port", "replacement": DEFAULT_METRICS_PORT},
        {"source_labels": [PORT_ANNOTATION], "regex": "(\\d+)", "target_label": "__tmp_port"},
        {"source_labels": ["__meta_kubernetes_pod_ip", "__tmp_port"], "regex": "(.+);(.+)",
         "replacement": "$1:$2", "target_label": "__address__"},
        {"source_labels": [PATH_ANNOTATION], "regex": "(.+)", "target_label": "__metrics_path__"},
        {"source_labels": ["__meta_kubernetes_namespace"], "target_label": "namespace"},
        {"source_labels": ["__meta_kubernetes_pod_name"], "target_label": "pod"},
        {"source_labels": ["__meta_kubernetes_pod_node_name"], "target_label": "node"},
    ]  # fmt: skip
    return {
        "job_name": "kubernetes-pods",
        "kubernetes_sd_configs": sd,
        "relabel_configs": relabel,
    }


def service_objects(prometheus_port: int) -> list[dict[str, Any]]:
    """The ``monitoring`` namespace and both Services with their EndpointSlices."""

    def slice_(name: str, ns: str, service: str, ports: list[dict[str, Any]]) -> dict[str, Any]:
        return {
            "apiVersion": "discovery.k8s.io/v1",
            "kind": "EndpointSlice",
            "metadata": {
                "name": name,
                "namespace": ns,
                "labels": {
                    "kubernetes.io/service-name": service,
                    "endpointslice.kubernetes.io/managed-by": "fogfleet-e2e-harness",
                },
            },
            "addressType": "IPv4",
            "endpoints": [{"addresses": [BRIDGE_IP], "conditions": {"ready": True}}],
            "ports": ports,
        }

    dns_ports = [
        {"name": "dns", "port": DNS_PORT, "protocol": "UDP"},
        {"name": "dns-tcp", "port": DNS_PORT, "protocol": "TCP"},
    ]
    return [
        {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": MONITORING_NAMESPACE}},
        {
            "apiVersion": "v1",
            "kind": "Service",
            "metadata": {
                "name": "prometheus",
                "namespace": MONITORING_NAMESPACE,
                "labels": {"app.kubernetes.io/name": "prometheus"},
            },
            "spec": {
                "ports": [{"name": "web", "port": PROMETHEUS_SERVICE_PORT, "protocol": "TCP"}]
            },
        },
        slice_(
            "prometheus-bed",
            MONITORING_NAMESPACE,
            "prometheus",
            [{"name": "web", "port": prometheus_port, "protocol": "TCP"}],
        ),
        {
            "apiVersion": "v1",
            "kind": "Service",
            "metadata": {
                "name": "kube-dns",
                "namespace": "kube-system",
                "labels": {"k8s-app": "kube-dns", "kubernetes.io/name": "CoreDNS"},
            },
            "spec": {"clusterIP": DNS_SERVICE_IP, "ports": dns_ports},
        },
        slice_("kube-dns-bed", "kube-system", "kube-dns", dns_ports),
    ]


def corefile(ports: Mapping[str, int], kubeconfig: Path) -> str:
    """``cluster.local`` from the API, on the bridge address only; every other zone REFUSED."""
    return f"""{CLUSTER_DOMAIN}:{DNS_PORT} {{
    bind {BRIDGE_IP}
    errors
    health {HOST}:{ports["coredns-health"]}
    ready {HOST}:{ports["coredns-ready"]}
    kubernetes {CLUSTER_DOMAIN} {{
        kubeconfig {kubeconfig} fogfleet-e2e
        pods disabled
        ttl 5
    }}
    cache 5
}}
"""


def coredns_argv(bin_dir: Path, ports: Mapping[str, int], api_server: str) -> list[str]:
    """Write CoreDNS's kubeconfig and Corefile into the state dir; its command line."""
    pki = STATE_DIR / "pki"
    kc = STATE_DIR / "coredns.kubeconfig"
    kc.write_text(kubeconfig(api_server, COREDNS_USER, pki / "coredns.crt", pki / "coredns.key"))
    kc.chmod(0o600)
    conf = STATE_DIR / "Corefile"
    conf.write_text(corefile(ports, kc))
    return [str(bin_dir / "coredns"), "-conf", str(conf)]


def dump(objects: list[dict[str, Any]]) -> str:
    """A kubectl apply input of several objects."""
    return json.dumps({"apiVersion": "v1", "kind": "List", "items": objects})
