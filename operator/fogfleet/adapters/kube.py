"""The Kubernetes API, as fogfleet uses it: a KubePort over the official client's REST layer.

Raw JSON in and out (camelCase, as on the wire): the controllers work on dicts, and the typed
client models would only be converted back. Every call blocks; controllers run it in a worker
thread. Library exceptions are translated into the fogfleet error tree in one place,
:func:`map_errors` (httpx's ``map_httpcore_exceptions``), always ``raise ... from exc``.

Every request is counted as client-go counts it, ``rest_client_requests_total{code,method,
host}`` (``metrics``): the API writes per second are its rate over PATCH, POST, PUT and DELETE.

Verbs used (the chart's ClusterRole must grant exactly these):

    fogfleet.io  robotfleets                 get list watch patch   (kopf: patch annotations)
    fogfleet.io  robotfleets/status          patch
    fogfleet.io  softwaremodules             get list watch patch   (the scaler's annotation)
    fogfleet.io  softwaremodules/status      patch                  (scaling, usage)
    fogfleet.io  computenodes                get list watch
    fogfleet.io  computenodes/status         patch                  (usage, readiness)
    fogfleet.io  explanationrequests         get list watch delete  (answered, then expired)
    fogfleet.io  explanationrequests/status  patch                  (the answer)
    ""           nodes                       get list watch
    ""           pods                        list watch
    ""           events                      create
    apps         deployments                 get list watch patch delete
    ""           services                    get list watch patch delete  (ROS discovery servers)
    networking.k8s.io  networkpolicies       get list watch patch         (one per fleet)
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import secrets
import time
import urllib.parse
from collections.abc import Iterator, Mapping
from typing import Any

import urllib3
from kubernetes import client, config
from kubernetes.client.exceptions import ApiException, OpenApiException
from kubernetes.config.config_exception import ConfigException

from fogfleet import GROUP, VERSION
from fogfleet.adapters.informer import WatchExpired
from fogfleet.adapters.ports import ClientMetrics
from fogfleet.api.kinds import COMPUTENODES, EXPLANATIONREQUESTS, ROBOTFLEETS, SOFTWAREMODULES
from fogfleet.api.labels import LABEL_FLEET, LABEL_MANAGED_BY, MANAGER
from fogfleet.api.timestamps import timestamp
from fogfleet.contract.quantity import parse_quantity
from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = ["KubeClient", "load_config", "map_errors"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
APPLY = "application/apply-patch+yaml"
MERGE = "application/merge-patch+json"
TIMEOUT = (5, 30)  # connect, read seconds
JSON = "application/json"
# a list of the objects' metadata only (the API server's PartialObjectMetadataList)
METADATA_ONLY = "application/json;as=PartialObjectMetadataList;v=v1;g=meta.k8s.io"
POOL_SIZE = 32  # HTTP connections kept: parallel applies, informers' watches, kopf's own


def load_config(kubeconfig: str | None = None) -> client.ApiClient:
    """An ApiClient from a kubeconfig file, $KUBECONFIG, ~/.kube/config or the in-cluster token."""
    with map_errors("load the Kubernetes configuration"):
        cfg = client.Configuration()
        try:
            config.load_kube_config(config_file=kubeconfig, client_configuration=cfg)  # type: ignore[no-untyped-call]
        except (ConfigException, FileNotFoundError, TypeError):
            if kubeconfig:
                raise
            config.load_incluster_config(client_configuration=cfg)  # type: ignore[no-untyped-call]
        cfg.connection_pool_maxsize = max(cfg.connection_pool_maxsize or 0, POOL_SIZE)
        return client.ApiClient(cfg)


@contextlib.contextmanager
def map_errors(what: str, obj: str = "") -> Iterator[None]:
    """Translate client-library errors into fogfleet errors (the only place that does so)."""
    try:
        yield
    except ApiException as exc:
        status = int(exc.status or 0)
        detail = _reason(exc)
        if status in (400, 422):
            raise InvalidSpec(obj or what, "", f"the API server rejected it: {detail}") from exc
        if status == 403:
            raise DependencyUnavailable(
                f"Cannot {what}: forbidden ({detail}); check the RBAC"
            ) from exc
        raise DependencyUnavailable(f"Cannot {what}: HTTP {status} {detail}") from exc
    except (urllib3.exceptions.HTTPError, OSError, ConfigException, OpenApiException) as exc:
        raise DependencyUnavailable(f"Cannot {what}: {exc}") from exc


def _reason(exc: ApiException) -> str:
    try:
        body = json.loads(exc.body or "{}")
        return str(body.get("message") or exc.reason)
    except (ValueError, TypeError):
        return str(exc.reason)


def _explanations(namespace: str, name: str = "") -> str:
    path = f"/apis/{GROUP}/{VERSION}/namespaces/{namespace}/{EXPLANATIONREQUESTS}"
    return f"{path}/{name}" if name else path


def _selector(labels: Mapping[str, str]) -> str:
    return ",".join(f"{k}={v}" for k, v in sorted(labels.items()))


class KubeClient:
    """KubePort over one ApiClient (thread-safe: urllib3's pool is)."""

    def __init__(
        self,
        api: client.ApiClient,
        *,
        manager: str = MANAGER,
        instance: str = "fogfleet",
        metrics: ClientMetrics | None = None,
    ) -> None:
        self.api = api
        self.timeout: tuple[float, float] = (
            TIMEOUT  # (connect, read) seconds of each request but a watch
        )
        self.manager = manager
        self.instance = instance
        self.metrics = metrics
        self.host = urllib.parse.urlsplit(str(api.configuration.host or "")).netloc

    def connection_info(self) -> dict[str, Any]:
        """Our credentials, as keyword arguments of kopf.ConnectionInfo (kopf logs in with them)."""
        cfg = self.api.configuration
        header = cfg.get_api_key_with_prefix("BearerToken") or cfg.get_api_key_with_prefix(
            "authorization"
        )
        parts = header.split(" ", 1) if header else []
        scheme, token = (
            (None, None) if not parts else (None, parts[0]) if len(parts) == 1 else parts
        )
        return {
            "server": cfg.host,
            "ca_path": cfg.ssl_ca_cert,
            "insecure": not cfg.verify_ssl,
            "scheme": scheme,
            "token": token,
            "certificate_path": cfg.cert_file,
            "private_key_path": cfg.key_file,
            "default_namespace": None,
        }

    # ---------------------------------------------------------------- raw REST
    def _call(
        self,
        method: str,
        path: str,
        *,
        query: Mapping[str, Any] | None = None,
        body: Any = None,
        content_type: str | None = None,
        missing_ok: bool = False,
        accept: str = JSON,
    ) -> Obj | None:
        resp = self._request(
            method,
            path,
            query=query,
            body=body,
            content_type=content_type,
            accept=accept,
            timeout=self.timeout,
        )
        data = resp.read()
        if resp.status == 404 and missing_ok:
            return None
        if not 200 <= resp.status < 300:
            raise ApiException(http_resp=resp)
        parsed: Obj = json.loads(data) if data else {}
        return parsed

    def _request(
        self,
        method: str,
        path: str,
        *,
        query: Mapping[str, Any] | None = None,
        body: Any = None,
        content_type: str | None = None,
        timeout: tuple[float, float] = TIMEOUT,
        accept: str = JSON,
    ) -> Any:
        """The response, its body not read yet (a watch streams it)."""
        headers = {"Accept": accept}
        if content_type:
            headers["Content-Type"] = content_type
        elif body is not None:
            headers["Content-Type"] = "application/json"
        url_path = path
        if query:
            url_path += "?" + urllib.parse.urlencode(
                {k: v for k, v in query.items() if v is not None}
            )
        m, url, hdrs, payload, _ = self.api.param_serialize(
            method=method,
            resource_path=url_path,
            header_params=headers,
            body=body,
            auth_settings=["BearerToken"],
        )
        try:
            resp = self.api.call_api(
                m, url, header_params=hdrs, body=payload, _request_timeout=timeout
            )
        except Exception:
            self._count(method, "<error>")  # no response: client-go's code for it
            raise
        self._count(method, str(resp.status))
        return resp

    def _count(self, method: str, code: str) -> None:
        if self.metrics is not None:
            self.metrics.count_request(code, method, self.host)

    def _list(
        self,
        path: str,
        what: str,
        selector: Mapping[str, str] | str | None = None,
        *,
        fields: str | None = None,
        accept: str = JSON,
    ) -> list[Obj]:
        """The items under ``path``: ``selector`` a label selector (labels, or its text),
        ``fields`` a field selector; ``accept`` ``METADATA_ONLY`` lists their metadata."""
        text = selector if isinstance(selector, str) else _selector(selector or {})
        query = {"labelSelector": text or None, "fieldSelector": fields}
        with map_errors(what):
            body = self._call("GET", path, query=query, accept=accept) or {}
        items: list[Obj] = body.get("items") or []
        return items

    # ---------------------------------------------------------------- list + watch (informers)
    def list_versioned(
        self, path: str, selector: Mapping[str, str] | None
    ) -> tuple[list[Obj], str]:
        """Every object under ``path`` and the list's resourceVersion (to watch from)."""
        query = {"labelSelector": _selector(selector)} if selector else None
        with map_errors(f"list {path}"):
            body = self._call("GET", path, query=query) or {}
        version = str((body.get("metadata") or {}).get("resourceVersion") or "")
        return list(body.get("items") or []), version

    def watch(
        self,
        path: str,
        selector: Mapping[str, str] | None,
        version: str,
        seconds: int,
        *,
        fields: str | None = None,
    ) -> Iterator[Obj]:
        """Watch events from ``version`` for up to ``seconds`` (with bookmarks); ``fields`` a
        field selector."""
        query = {
            "watch": "true",
            "resourceVersion": version,
            "timeoutSeconds": seconds,
            "allowWatchBookmarks": "true",
            "labelSelector": _selector(selector) if selector else None,
            "fieldSelector": fields,
        }
        with map_errors(f"watch {path}"):
            resp = self._request("GET", path, query=query, timeout=(5, seconds + 30))
            try:
                if resp.status == 410:
                    raise WatchExpired(path)
                if not 200 <= resp.status < 300:
                    resp.read()
                    raise ApiException(http_resp=resp)
                pending = b""
                for chunk in resp.response.stream(amt=None, decode_content=True):
                    pending += chunk
                    *lines, pending = pending.split(b"\n")
                    for line in lines:
                        if line.strip():
                            yield json.loads(line)
            finally:
                resp.response.close()  # a watch ended early leaves unread bytes: no reuse

    # ---------------------------------------------------------------- reads
    def get_fleet(self, namespace: str, name: str) -> Obj | None:
        with map_errors(f"read RobotFleet {namespace}/{name}"):
            return self._call(
                "GET",
                f"/apis/{GROUP}/{VERSION}/namespaces/{namespace}/{ROBOTFLEETS}/{name}",
                missing_ok=True,
            )

    def list_fleets(self, namespace: str | None = None) -> list[Obj]:
        where = f"/namespaces/{namespace}" if namespace else ""
        return self._list(f"/apis/{GROUP}/{VERSION}{where}/{ROBOTFLEETS}", "list RobotFleets")

    def list_compute_nodes(self) -> list[Obj]:
        return self._list(f"/apis/{GROUP}/{VERSION}/{COMPUTENODES}", "list ComputeNodes")

    def list_modules(self, namespace: str | None) -> list[Obj]:
        where = f"/namespaces/{namespace}" if namespace else ""
        return self._list(
            f"/apis/{GROUP}/{VERSION}{where}/{SOFTWAREMODULES}",
            f"list SoftwareModules in {namespace or 'all namespaces'}",
        )

    def list_nodes(self) -> list[Obj]:
        return self._list("/api/v1/nodes", "list Nodes")

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            f"/apis/apps/v1/namespaces/{namespace}/deployments",
            f"list Deployments in {namespace}",
            selector,
        )

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            f"/api/v1/namespaces/{namespace}/pods", f"list Pods in {namespace}", selector
        )

    def list_deployment_metadata(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        """The metadata of the Deployments ``selector`` selects (a PartialObjectMetadataList:
        no spec or status; a 1000-robot fleet's 8000 Deployments in a fraction of the bytes).
        Each item is ``{"metadata": ...}``."""
        return self._list(
            f"/apis/apps/v1/namespaces/{namespace}/deployments",
            f"list Deployments in {namespace}",
            selector,
            accept=METADATA_ONLY,
        )

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        """Every Pod bound to a node and not finished, as ``pod_load`` trims it (what it
        requests there and whose it is): what fleets share nodes with. ``besides`` (namespace,
        fleet label value): leave that fleet's own pods out, on the API server's side (what
        others hold is all a fleet reads; a 1000-robot fleet's own pods are 8000)."""
        if besides is None:
            found = self._list("/api/v1/pods", "list Pods on every node")
        else:
            namespace, fleet = besides
            found = self._list("/api/v1/pods", "list Pods on every node", f"{LABEL_FLEET}!={fleet}")
            found += self._list(  # a fleet of the same name in another namespace
                "/api/v1/pods",
                "list Pods on every node",
                {LABEL_FLEET: fleet},
                fields=f"metadata.namespace!={namespace}",
            )
        return [load for load in map(pod_load, found) if holds_room(load)]

    # ---------------------------------------------------------------- writes
    def _server_side_apply(self, kind: str, collection: str, body: Obj) -> Obj:
        """Server-side apply under the ``fogfleet`` field manager, forcing conflicts."""
        ns, name = body["metadata"]["namespace"], body["metadata"]["name"]
        with map_errors(f"apply {kind} {ns}/{name}", f"{kind}/{name}"):
            out = self._call(
                "PATCH",
                f"{collection.format(ns=ns)}/{name}",
                query={"fieldManager": self.manager, "force": "true"},
                body=body,
                content_type=APPLY,
            )
        return out or {}

    def apply_deployment(self, body: Obj) -> Obj:
        return self._server_side_apply(
            "Deployment", "/apis/apps/v1/namespaces/{ns}/deployments", body
        )

    def apply_service(self, body: Obj) -> Obj:
        """A Service as stored (with its cluster IP)."""
        return self._server_side_apply("Service", "/api/v1/namespaces/{ns}/services", body)

    def apply_network_policy(self, body: Obj) -> Obj:
        return self._server_side_apply(
            "NetworkPolicy", "/apis/networking.k8s.io/v1/namespaces/{ns}/networkpolicies", body
        )

    def list_network_policies(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            f"/apis/networking.k8s.io/v1/namespaces/{namespace}/networkpolicies",
            f"list NetworkPolicies in {namespace}",
            selector,
        )

    def delete_network_policy(self, namespace: str, name: str) -> None:
        path = f"/apis/networking.k8s.io/v1/namespaces/{namespace}/networkpolicies/{name}"
        with map_errors(f"delete NetworkPolicy {namespace}/{name}"):
            self._call("DELETE", path, missing_ok=True)

    def list_services(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            f"/api/v1/namespaces/{namespace}/services", f"list Services in {namespace}", selector
        )

    def delete_service(self, namespace: str, name: str) -> None:
        with map_errors(f"delete Service {namespace}/{name}"):
            self._call("DELETE", f"/api/v1/namespaces/{namespace}/services/{name}", missing_ok=True)

    def _delete_with_pods(self, kind: str, path: str) -> None:
        """Delete an object whose pods the garbage collector then removes; missing is fine."""
        with map_errors(f"delete {kind} {path.rsplit('/', 1)[-1]}"):
            self._call("DELETE", path, body={"propagationPolicy": "Background"}, missing_ok=True)

    def delete_deployment(self, namespace: str, name: str) -> None:
        self._delete_with_pods(
            "Deployment", f"/apis/apps/v1/namespaces/{namespace}/deployments/{name}"
        )

    def create_job(self, body: Obj) -> Obj:
        ns, name = body["metadata"]["namespace"], body["metadata"]["name"]
        path = f"/apis/batch/v1/namespaces/{ns}/jobs"
        with map_errors(f"create Job {ns}/{name}", f"Job/{name}"):
            try:
                return self._call("POST", path, body=body) or {}
            except ApiException as exc:
                if exc.status != 409:  # AlreadyExists: a Job of this name is this run's
                    raise
                return self._call("GET", f"{path}/{name}") or {}

    def list_jobs(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return self._list(
            f"/apis/batch/v1/namespaces/{namespace}/jobs", f"list Jobs in {namespace}", selector
        )

    def list_job_pods(self, namespace: str, job: str) -> list[Obj]:
        return KubeClient.list_pods(self, namespace, {"batch.kubernetes.io/job-name": job})

    def delete_job(self, namespace: str, name: str) -> None:
        self._delete_with_pods("Job", f"/apis/batch/v1/namespaces/{namespace}/jobs/{name}")

    def _merge_patch(self, what: str, path: str, body: Mapping[str, Any]) -> None:
        """A JSON merge patch of one fogfleet object (a missing object is not an error);
        ``path`` is ``<namespace>/<plural>/<name>...`` or ``/<plural>/<name>...`` for a
        cluster-scoped kind."""
        where = path if path.startswith("/") else f"/namespaces/{path}"
        self._merge_patch_at(what, f"/apis/{GROUP}/{VERSION}{where}", body)

    def _merge_patch_at(self, what: str, url_path: str, body: Mapping[str, Any]) -> None:
        """A JSON merge patch of the object at ``url_path`` (a missing object is not an error)."""
        with map_errors(what):
            self._call("PATCH", url_path, body=dict(body), content_type=MERGE, missing_ok=True)

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        self._merge_patch(
            f"patch the status of SoftwareModule {namespace}/{name}",
            f"{namespace}/{SOFTWAREMODULES}/{name}/status",
            {"status": dict(status)},
        )

    def patch_compute_node_status(self, name: str, status: Mapping[str, Any]) -> None:
        self._merge_patch(
            f"patch the status of ComputeNode {name}",
            f"/{COMPUTENODES}/{name}/status",
            {"status": dict(status)},
        )

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None:
        self._merge_patch(
            f"annotate SoftwareModule {namespace}/{name}",
            f"{namespace}/{SOFTWAREMODULES}/{name}",
            {"metadata": {"annotations": dict(annotations)}},
        )

    def patch_fleet_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        self._merge_patch(
            f"patch the status of RobotFleet {namespace}/{name}",
            f"{namespace}/{ROBOTFLEETS}/{name}/status",
            {"status": dict(status)},
        )

    def patch_explanation_status(
        self, namespace: str, name: str, status: Mapping[str, Any]
    ) -> None:
        self._merge_patch(
            f"answer ExplanationRequest {namespace}/{name}",
            f"{namespace}/{EXPLANATIONREQUESTS}/{name}/status",
            {"status": dict(status)},
        )

    def delete_explanation_request(self, namespace: str, name: str) -> None:
        with map_errors(f"delete ExplanationRequest {namespace}/{name}"):
            self._call("DELETE", _explanations(namespace, name), missing_ok=True)

    def ask_explanation(
        self, namespace: str, spec: Mapping[str, Any], seconds: float
    ) -> Obj | None:
        """Create an ExplanationRequest of ``spec``, wait up to ``seconds`` for the operator's
        answer and delete the request: the request as answered, None when no answer came."""
        body = {
            "apiVersion": f"{GROUP}/{VERSION}",
            "kind": "ExplanationRequest",
            "metadata": {"generateName": "why-", "labels": {LABEL_MANAGED_BY: self.manager}},
            "spec": {k: v for k, v in spec.items() if v is not None},
        }
        with map_errors(f"ask the operator (ExplanationRequest in {namespace})"):
            created = self._call("POST", _explanations(namespace), body=body) or {}
        meta = created.get("metadata") or {}
        name = str(meta.get("name") or "")
        try:
            return self._answer_of(namespace, name, str(meta.get("resourceVersion") or ""), seconds)
        finally:
            self.delete_explanation_request(namespace, name)

    def _answer_of(self, namespace: str, name: str, version: str, seconds: float) -> Obj | None:
        """The request once its status has a phase (watched from ``version``), or None."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            for event in self.watch(
                _explanations(namespace),
                None,
                version,
                max(1, math.ceil(left)),
                fields=f"metadata.name={name}",
            ):
                obj = event.get("object") or {}
                if event.get("type") == "BOOKMARK":
                    version = str((obj.get("metadata") or {}).get("resourceVersion") or version)
                    continue
                if event.get("type") == "DELETED":
                    return None
                if (obj.get("status") or {}).get("phase"):
                    return obj
                version = str((obj.get("metadata") or {}).get("resourceVersion") or version)
        return None

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None:
        meta = involved.get("metadata") or {}
        ns = meta.get("namespace") or "default"
        now_s = timestamp()
        event = {
            "apiVersion": "v1",
            "kind": "Event",
            "metadata": {
                "name": f"{meta.get('name', 'fogfleet')}.{secrets.token_hex(8)}",
                "namespace": ns,
            },
            "involvedObject": {
                "apiVersion": involved.get("apiVersion"),
                "kind": involved.get("kind"),
                "name": meta.get("name"),
                "namespace": ns,
                "uid": meta.get("uid"),
                "resourceVersion": meta.get("resourceVersion"),
            },
            "type": type_,
            "reason": reason,
            "message": message[:1024],
            "source": {"component": self.manager},
            "reportingComponent": self.manager,
            "reportingInstance": self.instance,
            "firstTimestamp": now_s,
            "lastTimestamp": now_s,
            "count": 1,
        }
        try:
            with map_errors(f"post an Event about {meta.get('name')}"):
                self._call("POST", f"/api/v1/namespaces/{ns}/events", body=event)
        except DependencyUnavailable as exc:  # an Event is best effort
            log.warning("Failed to post event %s: %s", reason, exc)


def pod_load(pod: Mapping[str, Any]) -> Obj:
    """A Pod as the tenancy of its node sees it: its name, the fleet and manager labels, its
    node and phase, and the CPU cores and memory bytes its containers request."""
    meta = pod.get("metadata") or {}
    spec = pod.get("spec") or {}
    cpu = memory = 0.0
    for container in spec.get("containers") or []:
        requests = (container.get("resources") or {}).get("requests") or {}
        try:
            cpu += parse_quantity(requests.get("cpu", 0))
            memory += parse_quantity(requests.get("memory", 0))
        except ValueError:
            continue  # the API server validated it; a form we do not read counts as 0
    labels = meta.get("labels") or {}
    return {
        "metadata": {
            "name": meta.get("name"),
            "namespace": meta.get("namespace"),
            "resourceVersion": meta.get("resourceVersion"),
            "labels": {k: labels[k] for k in (LABEL_FLEET, LABEL_MANAGED_BY) if k in labels},
        },
        "spec": {"nodeName": spec.get("nodeName")},
        "status": {"phase": (pod.get("status") or {}).get("phase")},
        "requests": {"cpu": cpu, "memory": memory},
    }


def holds_room(load: Mapping[str, Any]) -> bool:
    """Bound to a node and not finished: its requests count against the node."""
    phase = (load.get("status") or {}).get("phase")
    return bool((load.get("spec") or {}).get("nodeName")) and phase not in ("Succeeded", "Failed")
