"""The ports the controllers talk through (Protocols), so tests can plug in fakes.

Objects cross these ports as plain JSON-shaped dicts, exactly as the API server sends them
(camelCase keys). Every method is blocking: controllers call them from a worker thread, never
from the event loop. Implementations raise only the fogfleet error tree
(``DependencyUnavailable`` for anything the cluster did wrong, ``InvalidSpec`` when the API
server rejects what we sent).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

__all__ = [
    "ClientMetrics",
    "HubPort",
    "KubePort",
    "Listener",
    "MetricsPort",
    "NullMetrics",
    "SeriesPort",
    "Watches",
]

Obj = dict[str, Any]


class KubePort(Protocol):
    def get_fleet(self, namespace: str, name: str) -> Obj | None: ...

    def list_fleets(self, namespace: str | None = None) -> list[Obj]: ...

    def list_compute_nodes(self) -> list[Obj]: ...

    def list_modules(self, namespace: str | None) -> list[Obj]:
        """SoftwareModules of one namespace (None: of every namespace)."""
        ...

    def list_nodes(self) -> list[Obj]: ...

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def list_node_load(self) -> list[Obj]:
        """Every Pod bound to a node and not finished, trimmed to what it requests
        (``adapters.kube.pod_load``)."""
        ...

    def apply_deployment(self, body: Obj) -> Obj:
        """Server-side apply under the ``fogfleet`` field manager, forcing conflicts."""
        ...

    def apply_service(self, body: Obj) -> Obj:
        """Server-side apply of a Service; returns it as stored (with its cluster IP)."""
        ...

    def apply_network_policy(self, body: Obj) -> Obj: ...

    def list_network_policies(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def delete_network_policy(self, namespace: str, name: str) -> None: ...

    def list_services(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def delete_service(self, namespace: str, name: str) -> None: ...

    def delete_deployment(self, namespace: str, name: str) -> None:
        """Delete (foreground of pods is left to the garbage collector); missing is fine."""
        ...

    def create_job(self, body: Obj) -> Obj:
        """Create a Job (a profiling run); one that exists already is returned as stored."""
        ...

    def list_jobs(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def list_job_pods(self, namespace: str, job: str) -> list[Obj]:
        """The pods of Job ``job``, from the API server (with their termination messages)."""
        ...

    def delete_job(self, namespace: str, name: str) -> None:
        """Delete a Job and its pods; missing is fine."""
        ...

    def patch_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """One JSON merge patch of the status subresource (None values remove fields)."""
        ...

    def patch_explanation_status(
        self, namespace: str, name: str, status: Mapping[str, Any]
    ) -> None: ...

    def delete_explanation_request(self, namespace: str, name: str) -> None: ...

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """A SoftwareModule's status subresource (the autoscaler's decision)."""
        ...

    def patch_compute_node_status(self, name: str, status: Mapping[str, Any]) -> None:
        """A ComputeNode's status subresource (which fleets use it, its Node's readiness)."""
        ...

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None:
        """A SoftwareModule's annotations (the autoscaler's state across restarts)."""
        ...

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None:
        """A core/v1 Event about ``involved`` (a fleet body); failures are logged, not raised."""
        ...


Listener = Callable[[str, Obj, Obj | None], None]
"""(event type, the object (its last state when DELETED), its previous state or None)."""


class Watches(Protocol):
    """Watch-fed caches behind a KubePort (``adapters.watched.WatchedKube``)."""

    def start(
        self,
        on_pod: Listener | None = None,
        on_deployment: Listener | None = None,
        on_node: Listener | None = None,
        on_module: Listener | None = None,
        on_compute_node: Listener | None = None,
    ) -> None:
        """Start watching fogfleet's Pods and Deployments, the Nodes, SoftwareModules and
        ComputeNodes (one watch per kind: kopf then watches only RobotFleets); the listeners
        are called on a watch thread, not the event loop."""
        ...

    def stop(self) -> None: ...


class SeriesPort(Protocol):
    """Prometheus, as the link and drift passes query it."""

    def query_series(
        self, promql: str, *, obj: str = "", field: str = ""
    ) -> list[tuple[dict[str, str], float]]:
        """Every series of an instant query with its labels (NaN values left out)."""
        ...


class MetricsPort(Protocol):
    def observe_plan(
        self,
        fleet: str,
        scheduler: str,
        seconds: float,
        objectives: Mapping[str, float],
        degraded: int = 0,
    ) -> None: ...

    def count_migrations(self, fleet: str, n: int) -> None: ...

    def count_error(self, fleet: str, reason: str) -> None: ...

    def count_apply(self, fleet: str, applied: int, pruned: int) -> None: ...

    def observe_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """The fleet's status as just computed (its conditions, links, active standbys)."""
        ...

    def forget_fleet(self, namespace: str, name: str) -> None: ...

    def init_controller(self, controller: str) -> None: ...

    def observe_reconcile(self, controller: str, result: str, seconds: float) -> None:
        """One reconcile (controller-runtime's result: success, error, requeue,
        requeue_after)."""
        ...

    def set_queue_depth(self, name: str, depth: int) -> None: ...

    def count_queue_add(self, name: str, retry: bool = False) -> None: ...


class HubPort(Protocol):
    """An Open Cluster Management hub (adapters.hub): its ManagedClusters, and the
    ManifestWorks the operator writes in a cluster's namespace there."""

    def list_managed_clusters(self) -> list[Obj]: ...

    def list_works(self, cluster: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def apply_work(self, body: Obj) -> Obj: ...

    def delete_work(self, cluster: str, name: str) -> None: ...


class ClientMetrics(Protocol):
    """What the API client and its informers count (client-go's names where it has them)."""

    def count_request(self, code: str, method: str, host: str) -> None: ...

    def count_watch_restart(self, kind: str, reason: str) -> None: ...

    def init_watch(self, kind: str) -> None:
        """A kind is watched: its restart series start at zero."""
        ...


class NullMetrics:
    """Metrics that go nowhere (tests, the CLI)."""

    def observe_plan(
        self,
        fleet: str,
        scheduler: str,
        seconds: float,
        objectives: Mapping[str, float],
        degraded: int = 0,
    ) -> None:
        return None

    def count_migrations(self, fleet: str, n: int) -> None:
        return None

    def count_error(self, fleet: str, reason: str) -> None:
        return None

    def count_apply(self, fleet: str, applied: int, pruned: int) -> None:
        return None

    def observe_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        return None

    def forget_fleet(self, namespace: str, name: str) -> None:
        return None

    def init_controller(self, controller: str) -> None:
        return None

    def observe_reconcile(self, controller: str, result: str, seconds: float) -> None:
        return None

    def set_queue_depth(self, name: str, depth: int) -> None:
        return None

    def count_queue_add(self, name: str, retry: bool = False) -> None:
        return None
