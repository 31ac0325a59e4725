"""The cluster side of ``kubectl fogfleet``: a kubeconfig (``--kubeconfig``, ``$KUBECONFIG``,
``~/.kube/config``) and context (``--context``, else the current one) into the operator's own
Kubernetes adapter (``adapters.kube.KubeClient``, which translates the client's errors), and
the default namespace: the context's, else ``default`` (as kubectl)."""

from __future__ import annotations

from kubernetes import client, config
from kubernetes.config.config_exception import ConfigException

from fogfleet.adapters.kube import KubeClient, map_errors

__all__ = ["connect"]


def connect(kubeconfig: str | None, context: str | None) -> tuple[KubeClient, str]:
    """A read-only use of the cluster (the plugin only lists and gets) and its namespace."""
    with map_errors("load the Kubernetes configuration"):
        cfg = client.Configuration()
        try:
            config.load_kube_config(  # type: ignore[no-untyped-call]
                config_file=kubeconfig, context=context, client_configuration=cfg
            )
            contexts, active = config.list_kube_config_contexts(config_file=kubeconfig)  # type: ignore[no-untyped-call]
            chosen = context or (active or {}).get("name")
            ctx = next((c for c in contexts or [] if c.get("name") == chosen), active or {})
            namespace = (ctx.get("context") or {}).get("namespace") or "default"
        except (ConfigException, FileNotFoundError, TypeError):
            if kubeconfig or context:
                raise
            config.load_incluster_config(client_configuration=cfg)  # type: ignore[no-untyped-call]
            namespace = "default"
        return KubeClient(client.ApiClient(cfg), manager="kubectl-fogfleet"), namespace
