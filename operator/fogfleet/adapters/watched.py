"""The Kubernetes API with watch-fed reads: a KubeClient whose list calls read informers.

One :class:`~fogfleet.adapters.informer.Informer` per kind the controllers list - Nodes,
ComputeNodes, SoftwareModules, and the Deployments and Pods that carry fogfleet's
``app.kubernetes.io/managed-by`` label - per served namespace (or one cluster-wide). A reconcile
then lists nothing: at 8000 pods a re-list costs seconds of JSON decoding and API-server time,
and it ran on every status refresh. Until an informer has its first list in (``synced``) the
same call goes to the API server, so the operator works from its first second.

Writes go to the API server as before (KubeClient); a Deployment we applied or deleted goes into
its cache at once, so the reconcile that wrote it reads its own write. What the cache serves of
Deployments and Pods is what carries the managed-by label - every object fogfleet creates does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from kubernetes import client

from fogfleet import GROUP, VERSION
from fogfleet.api.labels import LABEL_MANAGED_BY, MANAGER
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule

from .informer import Informer, OnEvent, trim_metadata
from .kube import KubeClient, holds_room, pod_load

__all__ = ["WatchedKube", "trim_deployment", "trim_node", "trim_pod"]

Obj = dict[str, Any]
POD_STATUS = ("phase", "conditions", "podIP", "podIPs", "startTime")


def trim_pod(pod: Obj) -> Obj:
    """What the controllers read of a Pod: metadata, its node, phase, conditions and IPs."""
    pod = trim_metadata(pod)
    status = pod.get("status") or {}
    return {
        "metadata": pod.get("metadata") or {},
        "spec": {"nodeName": (pod.get("spec") or {}).get("nodeName")},
        "status": {k: status[k] for k in POD_STATUS if k in status},
    }


def trim_deployment(dep: Obj) -> Obj:
    """A Deployment without its pod template's containers (the controllers read the spec hash
    annotation, the replicas, the template's node affinity and the status)."""
    dep = trim_metadata(dep)
    spec = dep.get("spec") or {}
    template = spec.get("template") or {}
    return {
        "metadata": dep.get("metadata") or {},
        "spec": {
            "replicas": spec.get("replicas", 1),
            "template": {
                "metadata": template.get("metadata") or {},
                "spec": {"affinity": (template.get("spec") or {}).get("affinity")},
            },
        },
        "status": dep.get("status") or {},
    }


def trim_node(node: Obj) -> Obj:
    """A Node without its image list (often most of its size)."""
    node = trim_metadata(node)
    status = node.get("status") or {}
    if "images" in status:
        node = {**node, "status": {k: v for k, v in status.items() if k != "images"}}
    return node


class WatchedKube(KubeClient):
    """KubePort reading informers once they are synced; see the module docstring."""

    def __init__(
        self, api: client.ApiClient, *, namespaces: Sequence[str] = (), **kwargs: Any
    ) -> None:
        super().__init__(api, **kwargs)
        self.namespaces: tuple[str, ...] = tuple(namespaces)
        scopes: tuple[str | None, ...] = self.namespaces or (None,)
        managed = {LABEL_MANAGED_BY: MANAGER}
        restarts = self.metrics.count_watch_restart if self.metrics is not None else None

        def per_scope(collection: str, prefix: str, kind: str, **kw: Any) -> dict[Any, Informer]:
            return {
                ns: Informer(
                    self,
                    f"{prefix}/namespaces/{ns}/{collection}" if ns else f"{prefix}/{collection}",
                    name=f"{kind} {ns or '*'}",
                    kind=kind.removesuffix("s"),
                    on_restart=restarts,
                    **kw,
                )
                for ns in scopes
            }

        crds = f"/apis/{GROUP}/{VERSION}"
        self.nodes = Informer(
            self, "/api/v1/nodes", trim=trim_node, name="Nodes", kind="Node", on_restart=restarts
        )
        self.compute_nodes = Informer(
            self,
            f"{crds}/{ComputeNode.PLURAL}",
            name="ComputeNodes",
            kind="ComputeNode",
            on_restart=restarts,
        )
        self.modules = per_scope(SoftwareModule.PLURAL, crds, "SoftwareModules")
        self.deployments = per_scope(
            "deployments", "/apis/apps/v1", "Deployments", selector=managed, trim=trim_deployment
        )
        self.pods = per_scope("pods", "/api/v1", "Pods", selector=managed, trim=trim_pod)
        # every Pod on every node, trimmed to its requests: what fleets share nodes with
        self.node_load = Informer(
            self,
            "/api/v1/pods",
            trim=pod_load,
            name="Pods (node load)",
            kind="Pod",
            on_restart=restarts,
        )

        if self.metrics is not None:
            for kind in sorted({i.kind for i in self.informers()}):
                self.metrics.init_watch(kind)

    def informers(self) -> list[Informer]:
        return [
            self.nodes,
            self.compute_nodes,
            *self.modules.values(),
            *self.deployments.values(),
            *self.pods.values(),
            self.node_load,
        ]

    def start(
        self,
        on_pod: OnEvent | None = None,
        on_deployment: OnEvent | None = None,
        on_node: OnEvent | None = None,
        on_module: OnEvent | None = None,
        on_compute_node: OnEvent | None = None,
    ) -> None:
        """Start every informer; the listeners hear each fogfleet Pod's and Deployment's and
        each Node's, SoftwareModule's and ComputeNode's changes (on the informer's thread)."""
        self.nodes.on_event = on_node
        self.compute_nodes.on_event = on_compute_node
        for informer in self.modules.values():
            informer.on_event = on_module
        for informer in self.pods.values():
            informer.on_event = on_pod
        for informer in self.deployments.values():
            informer.on_event = on_deployment
        for informer in self.informers():
            informer.start()

    def stop(self) -> None:
        for informer in self.informers():
            informer.stop()

    def cached_objects(self) -> int:
        """How many objects the caches hold (the operator's memory grows with this)."""
        return sum(i.size() for i in self.informers())

    @staticmethod
    def _serving(table: Mapping[str | None, Informer], namespace: str) -> Informer | None:
        """The informer holding ``namespace``'s objects (None: not a served namespace)."""
        return table[namespace] if namespace in table else table.get(None)

    @classmethod
    def _synced(cls, table: Mapping[str | None, Informer], namespace: str) -> Informer | None:
        informer = cls._serving(table, namespace)
        return informer if informer is not None and informer.synced.is_set() else None

    # ---------------------------------------------------------------- reads from the caches
    def list_nodes(self) -> list[Obj]:
        if self.nodes.synced.is_set():
            return self.nodes.list()
        return super().list_nodes()

    def list_compute_nodes(self) -> list[Obj]:
        if self.compute_nodes.synced.is_set():
            return self.compute_nodes.list()
        return super().list_compute_nodes()

    def list_modules(self, namespace: str | None) -> list[Obj]:
        if namespace is None:
            if not self.namespaces and self.modules[None].synced.is_set():
                return self.modules[None].list()
            return super().list_modules(namespace)
        informer = self._synced(self.modules, namespace)
        if informer is None:
            return super().list_modules(namespace)
        return informer.list(namespace)

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        informer = self._synced(self.deployments, namespace)
        if informer is None:
            return super().list_deployments(namespace, selector)
        return informer.list(namespace, selector)

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        informer = self._synced(self.pods, namespace)
        if informer is None:
            return super().list_pods(namespace, selector)
        return informer.list(namespace, selector)

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        """From the informer's cache once synced (it holds every Pod: ``besides`` filters
        nothing out then; ``held_by_others`` leaves the fleet's own out)."""
        if not self.node_load.synced.is_set():
            return super().list_node_load(besides)
        return [p for p in self.node_load.list() if holds_room(p)]

    # ---------------------------------------------------------------- writes, read back at once
    def apply_deployment(self, body: Obj) -> Obj:
        stored = super().apply_deployment(body)
        informer = self._serving(self.deployments, body["metadata"]["namespace"])
        if informer is not None and stored.get("metadata"):
            informer.put(stored)
        return stored

    def delete_deployment(self, namespace: str, name: str) -> None:
        super().delete_deployment(namespace, name)
        informer = self._serving(self.deployments, namespace)
        if informer is not None:
            informer.drop(namespace, name)
