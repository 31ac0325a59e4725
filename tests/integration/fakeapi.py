"""A small fake Kubernetes API server on 127.0.0.1, for running the real operator in-process.

It serves what kopf and ``fogfleet.adapters.kube`` use, for a fixed table of kinds:
discovery (``/version``, ``/api``, ``/apis``, ``/api/v1``, ``/apis/<group>/<version>``) and, per
collection, list (with ``labelSelector``), watch (``watch=true`` from a ``resourceVersion``,
one JSON event a line), get, create, delete and patch: JSON merge patch (RFC 7386: ``None``
removes a key), JSON patch (``test``/``add``/``replace``/``remove``) and server-side apply
(``application/apply-patch+yaml``; the applied body replaces the fields it names, the rest of
the stored object is kept). ``/status`` patches change only the status, other patches never
do; ``metadata.generation`` grows when the spec changes. One global resourceVersion counter
orders every write, as etcd's revision does.

Not faked: JSON patch (kopf sends it only for finalizers, which fogfleet does not use; it gets
a 415 here, so a change that needs it shows), admission, defaulting, field ownership between
managers, RBAC, pagination, resourceVersion expiry (410). Every request is recorded in
:attr:`FakeApi.requests` so tests assert on what the operator asked for. The server runs on its
own event loop in a thread, so the operator under test (kopf in KopfRunner's thread, our client
in its worker threads) talks to it over real sockets.
"""

from __future__ import annotations

import asyncio
import copy
import dataclasses
import json
import threading
import uuid
from collections.abc import Iterator, Mapping
from typing import Any

from aiohttp import web

__all__ = ["KINDS", "FakeApi", "Kind", "Request"]

Obj = dict[str, Any]


@dataclasses.dataclass(frozen=True)
class Kind:
    group: str
    version: str
    plural: str
    kind: str
    namespaced: bool
    status: bool = False  # has a /status subresource

    @property
    def api_version(self) -> str:
        return f"{self.group}/{self.version}" if self.group else self.version


KINDS = (
    Kind("", "v1", "nodes", "Node", False, status=True),
    Kind("", "v1", "namespaces", "Namespace", False, status=True),
    Kind("", "v1", "pods", "Pod", True, status=True),
    Kind("", "v1", "services", "Service", True, status=True),
    Kind("", "v1", "events", "Event", True),
    Kind("apps", "v1", "deployments", "Deployment", True, status=True),
    Kind("batch", "v1", "jobs", "Job", True, status=True),
    Kind("networking.k8s.io", "v1", "networkpolicies", "NetworkPolicy", True),
    Kind(
        "apiextensions.k8s.io",
        "v1",
        "customresourcedefinitions",
        "CustomResourceDefinition",
        False,
        status=True,
    ),
    Kind("fogfleet.io", "v1alpha1", "robotfleets", "RobotFleet", True, status=True),
    Kind("fogfleet.io", "v1alpha1", "softwaremodules", "SoftwareModule", True, status=True),
    Kind("fogfleet.io", "v1alpha1", "computenodes", "ComputeNode", False, status=True),
)
POLL_SECONDS = 0.02  # how soon a watch sees a write
VERBS = ["create", "delete", "get", "list", "patch", "watch"]


@dataclasses.dataclass(frozen=True)
class Request:
    method: str
    path: str
    query: Mapping[str, str]
    content_type: str
    body: Any


def merge_patch(target: Obj, patch: Mapping[str, Any]) -> Obj:
    """RFC 7386, as the API server applies ``application/merge-patch+json``."""
    out = copy.deepcopy(target)
    for key, value in patch.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = merge_patch(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _selected(labels: Mapping[str, str], selector: str) -> bool:
    for term in filter(None, selector.split(",")):
        if "!=" in term:
            key, value = term.split("!=", 1)
            if labels.get(key) == value:
                return False
        elif "=" in term:
            key, value = term.split("=", 1)
            if labels.get(key.rstrip("=")) != value:
                return False
        elif term.startswith("!"):
            if term[1:] in labels:
                return False
        elif term not in labels:
            return False
    return True


def _status(code: int, reason: str, message: str) -> web.Response:
    body = {
        "kind": "Status",
        "apiVersion": "v1",
        "status": "Failure",
        "code": code,
        "reason": reason,
        "message": message,
    }
    return web.json_response(body, status=code)


class FakeApi:
    """The fake API server; ``with FakeApi() as api:`` serves on ``api.url`` until the end."""

    def __init__(self, kinds: tuple[Kind, ...] = KINDS) -> None:
        self.kinds = {(k.group, k.version, k.plural): k for k in kinds}
        self.objects: dict[tuple[str, str, str], Obj] = {}  # (plural.group, ns, name) -> obj
        self.history: list[tuple[int, Kind, str, Obj]] = []  # (rv, kind, event type, obj)
        self.requests: list[Request] = []
        self.revision = 0
        self.url = ""
        self._lock = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="fake-api")
        self._runner: web.AppRunner | None = None

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> FakeApi:
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(timeout=10)
        return self

    def __exit__(self, *_: Any) -> None:
        if self._runner is not None:
            asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop).result(timeout=10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)
        self._loop.close()

    async def _start(self) -> None:
        app = web.Application()
        app.router.add_route("*", "/{path:.*}", self._handle)
        self._runner = web.AppRunner(
            app, handle_signals=False, access_log=None, shutdown_timeout=0.1
        )
        await self._runner.setup()
        site = web.TCPSite(self._runner, "127.0.0.1", 0)
        await site.start()
        port = site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]
        self.url = f"http://127.0.0.1:{port}"

    def kubeconfig(self) -> Obj:
        """A kubeconfig for this server (plain HTTP, a token nobody checks)."""
        return {
            "apiVersion": "v1",
            "kind": "Config",
            "clusters": [{"name": "fake", "cluster": {"server": self.url}}],
            "users": [{"name": "fake", "user": {"token": "fake-token"}}],
            "contexts": [{"name": "fake", "context": {"cluster": "fake", "user": "fake"}}],
            "current-context": "fake",
        }

    # ------------------------------------------------------------------ the test's side
    def _kind_of(self, obj: Mapping[str, Any]) -> Kind:
        group, _, version = obj["apiVersion"].rpartition("/")
        return next(
            k
            for k in self.kinds.values()
            if (k.group, k.version, k.kind) == (group, version, obj["kind"])
        )

    def create(self, obj: Obj) -> Obj:
        """Create ``obj`` (with ``apiVersion`` and ``kind``) as a client would."""
        kind = self._kind_of(obj)
        ns = obj["metadata"].get("namespace", "default") if kind.namespaced else ""
        with self._lock:
            return copy.deepcopy(self._write(kind, ns, obj["metadata"]["name"], obj))

    def get(self, kind: str, name: str, namespace: str = "") -> Obj | None:
        with self._lock:
            for (_, ns, n), obj in self.objects.items():
                if obj["kind"] == kind and n == name and ns == namespace:
                    return copy.deepcopy(obj)
        return None

    def list(self, kind: str, namespace: str | None = None) -> list[Obj]:
        with self._lock:
            return [
                copy.deepcopy(o)
                for (_, ns, _), o in self.objects.items()
                if o["kind"] == kind and namespace in (None, ns)
            ]

    def patch_status(self, kind: str, name: str, namespace: str, status: Obj) -> Obj:
        """What a controller of the cluster writes (the kubelet, the Deployment controller)."""
        with self._lock:
            key = next(
                k
                for k, o in self.objects.items()
                if o["kind"] == kind and k[1:] == (namespace, name)
            )
            old = self.objects[key]
            new = {**old, "status": merge_patch(old.get("status") or {}, status)}
            return copy.deepcopy(self._write(self._kind_of(old), namespace, name, new))

    def delete(self, kind: str, name: str, namespace: str = "") -> Obj | None:
        """Delete an object at once, as ``kubectl delete`` does one without finalizers (no
        garbage collector here: what it owns stays)."""
        with self._lock:
            found = next((k for k in self.kinds.values() if k.kind == kind), None)
            return None if found is None else self._delete(found, namespace, name)

    def requests_to(self, method: str, *, containing: str = "") -> Iterator[Request]:
        return (r for r in list(self.requests) if r.method == method and containing in r.path)

    # ------------------------------------------------------------------ the store
    def _write(self, kind: Kind, ns: str, name: str, obj: Obj) -> Obj:
        """Store ``obj`` as the new state (caller holds the lock) and record its event."""
        key = (f"{kind.plural}.{kind.group}", ns, name)
        old = self.objects.get(key)
        self.revision += 1
        new = copy.deepcopy(obj)
        new["apiVersion"], new["kind"] = kind.api_version, kind.kind
        meta = new.setdefault("metadata", {})
        meta["name"] = name
        if kind.namespaced:
            meta["namespace"] = ns
        meta["resourceVersion"] = str(self.revision)
        if old is None:
            meta["uid"] = str(uuid.uuid4())
            meta["creationTimestamp"] = "2026-01-01T00:00:00Z"
            meta["generation"] = 1
        else:
            meta["uid"] = old["metadata"]["uid"]
            meta["creationTimestamp"] = old["metadata"]["creationTimestamp"]
            changed = {k: v for k, v in new.items() if k not in ("metadata", "status")} != {
                k: v for k, v in old.items() if k not in ("metadata", "status")
            }
            meta["generation"] = old["metadata"].get("generation", 1) + changed
        self.objects[key] = new
        self._record(kind, "ADDED" if old is None else "MODIFIED", new)
        return new

    def _delete(self, kind: Kind, ns: str, name: str) -> Obj | None:
        old = self.objects.pop((f"{kind.plural}.{kind.group}", ns, name), None)
        if old is not None:
            self.revision += 1
            old = {**old, "metadata": {**old["metadata"], "resourceVersion": str(self.revision)}}
            self._record(kind, "DELETED", old)
        return old

    def _record(self, kind: Kind, event: str, obj: Obj) -> None:
        self.history.append((self.revision, kind, event, copy.deepcopy(obj)))

    # ------------------------------------------------------------------ HTTP
    async def _handle(self, request: web.Request) -> web.StreamResponse:
        raw = await request.read()
        body = json.loads(raw) if raw else None
        path = request.path.rstrip("/")
        self.requests.append(
            Request(request.method, path, dict(request.query), request.content_type, body)
        )
        if request.method == "GET" and path in ("/version", "/api", "/apis"):
            return web.json_response(self._discovery(path))
        parts = path.strip("/").split("/")
        if parts[0] == "api" and len(parts) >= 2:
            group, version, rest = "", parts[1], parts[2:]
        elif parts[0] == "apis" and len(parts) >= 3:
            group, version, rest = parts[1], parts[2], parts[3:]
        else:
            return _status(404, "NotFound", f"no route {path}")
        if not rest:
            return web.json_response(self._resources(group, version))
        ns = ""
        if rest[0] == "namespaces" and len(rest) >= 3:
            ns, rest = rest[1], rest[2:]
        plural, name, sub = [*rest, None, None][:3]
        kind = self.kinds.get((group, version, plural or ""))
        if kind is None:
            return _status(404, "NotFound", f"the server could not find {path}")
        if request.method == "GET" and name is None and request.query.get("watch") == "true":
            return await self._watch(request, kind, ns)
        with self._lock:
            return self._serve(request, kind, ns, name, sub, body)

    def _discovery(self, path: str) -> Obj:
        if path == "/version":
            return {"major": "1", "minor": "33", "gitVersion": "v1.33.0-fake"}
        if path == "/api":
            return {"kind": "APIVersions", "versions": ["v1"]}
        groups = sorted({(k.group, k.version) for k in self.kinds.values() if k.group})
        return {
            "kind": "APIGroupList",
            "groups": [
                {
                    "name": g,
                    "versions": [{"groupVersion": f"{g}/{v}", "version": v}],
                    "preferredVersion": {"groupVersion": f"{g}/{v}", "version": v},
                }
                for g, v in groups
            ],
        }

    def _resources(self, group: str, version: str) -> Obj:
        resources: list[Obj] = []
        for k in self.kinds.values():
            if (k.group, k.version) != (group, version):
                continue
            resources.append(
                {
                    "name": k.plural,
                    "singularName": k.kind.lower(),
                    "namespaced": k.namespaced,
                    "kind": k.kind,
                    "verbs": VERBS,
                }
            )
            if k.status:
                resources.append(
                    {
                        "name": f"{k.plural}/status",
                        "singularName": "",
                        "namespaced": k.namespaced,
                        "kind": k.kind,
                        "verbs": ["get", "patch"],
                    }
                )
        gv = f"{group}/{version}" if group else version
        return {"kind": "APIResourceList", "groupVersion": gv, "resources": resources}

    def _serve(
        self,
        request: web.Request,
        kind: Kind,
        ns: str,
        name: str | None,
        sub: str | None,
        body: Any,
    ) -> web.Response:
        key = (f"{kind.plural}.{kind.group}", ns, name or "")
        stored = self.objects.get(key)
        if name is None and request.method == "GET":
            selector = request.query.get("labelSelector", "")
            items = [
                o
                for (p, o_ns, _), o in self.objects.items()
                if p == key[0]
                and (not ns or o_ns == ns)
                and _selected(o["metadata"].get("labels") or {}, selector)
            ]
            return web.json_response(
                {
                    "apiVersion": kind.api_version,
                    "kind": f"{kind.kind}List",
                    "items": items,
                    "metadata": {"resourceVersion": str(self.revision)},
                }
            )
        if name is None and request.method == "POST":
            name = body["metadata"].get("name") or f"{body['metadata']['generateName']}x"
            if (key[0], ns, name) in self.objects:
                return _status(409, "AlreadyExists", f"{kind.plural} {name!r} already exists")
            return web.json_response(self._write(kind, ns, name, body), status=201)
        if name is None:
            return _status(405, "MethodNotAllowed", f"{request.method} on a collection")
        if request.method == "GET":
            return web.json_response(stored) if stored else _status(404, "NotFound", name)
        if request.method == "DELETE":
            gone = self._delete(kind, ns, name)
            return web.json_response(gone) if gone else _status(404, "NotFound", name)
        if request.method != "PATCH":
            return _status(405, "MethodNotAllowed", request.method)
        return self._patch(request.content_type, kind, ns, name, sub, stored, body)

    def _patch(
        self,
        content_type: str,
        kind: Kind,
        ns: str,
        name: str,
        sub: str | None,
        stored: Obj | None,
        body: Any,
    ) -> web.Response:
        if content_type == "application/apply-patch+yaml":
            base = stored or {}
            new = {**base, **{k: v for k, v in body.items() if k != "status"}}
            new["metadata"] = {**base.get("metadata", {}), **body.get("metadata", {})}
            return web.json_response(self._write(kind, ns, name, new))
        if stored is None:
            return _status(404, "NotFound", f"{kind.plural} {name!r} not found")
        if content_type == "application/merge-patch+json":
            patched = merge_patch(stored, body)
        else:
            return _status(415, "UnsupportedMediaType", content_type)
        if sub == "status":  # only the status changes through /status ...
            new = {**stored, "status": patched.get("status") or {}}
        else:  # ... and never through the object itself
            new = {**patched, "status": stored.get("status")} if "status" in stored else patched
        return web.json_response(self._write(kind, ns, name, new))

    async def _watch(self, request: web.Request, kind: Kind, ns: str) -> web.StreamResponse:
        since = int(request.query.get("resourceVersion") or 0)
        selector = request.query.get("labelSelector", "")
        deadline = self._loop.time() + float(request.query.get("timeoutSeconds") or 300)
        response = web.StreamResponse(headers={"Content-Type": "application/json"})
        await response.prepare(request)
        seen = 0
        try:
            while self._loop.time() < deadline:
                with self._lock:
                    fresh = self.history[seen:]
                    seen = len(self.history)
                for rv, k, event, obj in fresh:
                    if rv <= since or k != kind:
                        continue
                    if ns and obj["metadata"].get("namespace") != ns:
                        continue
                    if not _selected(obj["metadata"].get("labels") or {}, selector):
                        continue
                    line = json.dumps({"type": event, "object": obj}) + "\n"
                    await response.write(line.encode())
                if len(self.history) == seen:
                    await asyncio.sleep(POLL_SECONDS)
        except (ConnectionResetError, asyncio.CancelledError):
            return response
        return response
