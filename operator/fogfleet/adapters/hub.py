"""The Open Cluster Management hub, as the operator uses it (issue 47; docs/multicluster.md):
it reads the ManagedClusters and writes one ManifestWork per instance planned into a managed
cluster. The hub's kubeconfig (FOGFLEET_HUB_KUBECONFIG) is the only credential the operator
holds beyond its own cluster's: never one of the managed clusters'.

The hub may be across the WAN from the site, and a WAN cut holds a request rather than
refusing it, so every request here gives up after ``HUB_TIMEOUT``, and for ``HUB_BACKOFF``
after one that got no answer every request fails at once: the reconciles of a cut-off site do
not each wait out the timeout. A reconcile that cannot reach the hub goes on with what it can
do at the site (``controllers.fleet.clusters``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

from kubernetes import client

from fogfleet.adapters.kube import KubeClient, load_config, map_errors
from fogfleet.adapters.ports import ClientMetrics
from fogfleet.errors import DependencyUnavailable

__all__ = ["HUB_TIMEOUT", "HubClient", "hub_client"]

Obj = dict[str, Any]
HUB_TIMEOUT = (3.0, 5.0)  # connect, read seconds
HUB_BACKOFF = 10.0  # seconds of failing at once after a request that got no answer
CLUSTERS = "/apis/cluster.open-cluster-management.io/v1/managedclusters"
ALL_WORKS = "/apis/work.open-cluster-management.io/v1/manifestworks"
WORKS = "/apis/work.open-cluster-management.io/v1/namespaces/{ns}/manifestworks"


class HubClient(KubeClient):
    """HubPort over one ApiClient of the hub."""

    def __init__(
        self,
        api: client.ApiClient,
        *,
        metrics: ClientMetrics | None = None,
        clock: Any = time.monotonic,
    ) -> None:
        super().__init__(api, metrics=metrics)
        self.timeout = HUB_TIMEOUT
        self.clock = clock
        self._lock = threading.Lock()
        self._silent: tuple[float, str] | None = None  # (until, why): the hub did not answer

    def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        with self._lock:
            silent = self._silent
        if silent is not None and self.clock() < silent[0]:
            raise DependencyUnavailable(f"the OCM hub did not answer ({silent[1]})")
        try:
            resp = super()._request(method, path, **kwargs)
        except Exception as exc:  # no answer at all: a timeout, a refused connection
            with self._lock:
                self._silent = (self.clock() + HUB_BACKOFF, type(exc).__name__)
            raise
        with self._lock:
            self._silent = None
        return resp

    def list_managed_clusters(self) -> list[Obj]:
        return self._list(CLUSTERS, "list the hub's ManagedClusters")

    def list_works(self, cluster: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            WORKS.format(ns=cluster), f"list the hub's ManifestWorks of {cluster}", selector
        )

    def apply_work(self, body: Obj) -> Obj:
        return self._server_side_apply("ManifestWork", WORKS, body)

    def list_all_works(self, selector: Mapping[str, str]) -> list[Obj]:
        """Every cluster's works (the hub keeper's: it runs on the hub)."""
        return self._list(ALL_WORKS, "list the hub's ManifestWorks", selector)

    def patch_work(self, cluster: str, name: str, patch: Mapping[str, Any]) -> None:
        what = f"patch ManifestWork {cluster}/{name}"
        self._merge_patch_at(what, f"{WORKS.format(ns=cluster)}/{name}", patch)

    def delete_work(self, cluster: str, name: str) -> None:
        with map_errors(f"delete ManifestWork {cluster}/{name}"):
            self._call("DELETE", f"{WORKS.format(ns=cluster)}/{name}", missing_ok=True)


def hub_client(kubeconfig: str, metrics: ClientMetrics | None = None) -> HubClient:
    """The hub's client, from its kubeconfig file."""
    return HubClient(load_config(kubeconfig), metrics=metrics)
