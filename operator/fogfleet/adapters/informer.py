"""A watch-fed cache of one kind (the part of client-go's reflector and store fogfleet needs).

An :class:`Informer` lists its objects once, then watches from the list's resourceVersion and
applies every event to an in-memory store, so reads cost no API call and no JSON decoding. When
the watch falls too far behind (HTTP 410 Gone, or a watch ``ERROR`` event) it lists again; when
the connection breaks it re-watches from the last resourceVersion it saw, backing off up to
:data:`MAX_BACKOFF_SECONDS` while the API server is unreachable. Watch bookmarks keep that
resourceVersion fresh on quiet kinds. Each restart but the API server's routine end of a watch
is reported (``on_restart(kind, reason)``: ``expired``, ``error`` or ``unexpected``), for
``fogfleet_watch_restarts_total``.

Objects are trimmed on the way in (``trim``): ``metadata.managedFields`` always, and for bulky
kinds everything the controllers never read, so the cache's memory grows with the number of
objects, not with their size. Readers get the stored dicts themselves: treat them as read-only.

Writes made by this process can be put in at once (:meth:`Informer.put`, :meth:`Informer.drop`)
so the next read sees them before their watch event arrives. A write never replaces a newer
version already seen, and a deleted object is not brought back by a late write: the store
compares resourceVersions (etcd's revision numbers; an opaque one is always taken).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Protocol

from fogfleet.errors import DependencyUnavailable

__all__ = [
    "MAX_BACKOFF_SECONDS",
    "Informer",
    "WatchExpired",
    "WatchSource",
    "matches",
    "trim_metadata",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
Key = tuple[str, str]  # (namespace or "", name)
Trim = Callable[[Obj], Obj]
OnEvent = Callable[[str, Obj, Obj | None], None]
OnRestart = Callable[[str, str], None]
"""(kind, reason): a watch restarted (expired: listed again; error: watched again; unexpected:
listed again after a bug)."""
"""(event type, the object (its last state when DELETED), its previous state or None)."""

MAX_BACKOFF_SECONDS = 30.0
MAX_TOMBSTONES = 4096  # deleted keys remembered (oldest forgotten first)
WATCH_SECONDS = 290  # the API server ends a watch after this; we re-watch from the last version


class WatchExpired(Exception):
    """The resourceVersion we watch from is gone (410): list again."""


class WatchSource(Protocol):
    """The two raw calls an informer needs (KubeClient implements them)."""

    def list_versioned(
        self, path: str, selector: Mapping[str, str] | None
    ) -> tuple[list[Obj], str]:
        """(items, the list's resourceVersion)."""
        ...

    def watch(
        self, path: str, selector: Mapping[str, str] | None, version: str, seconds: int
    ) -> Iterator[Obj]:
        """Watch events (``{"type": ..., "object": ...}``) from ``version`` for ``seconds``;
        raises WatchExpired on 410 Gone."""
        ...


def trim_metadata(obj: Obj) -> Obj:
    """The object without ``metadata.managedFields`` (often half of a small object)."""
    meta = obj.get("metadata")
    if isinstance(meta, dict) and "managedFields" in meta:
        obj = {**obj, "metadata": {k: v for k, v in meta.items() if k != "managedFields"}}
    return obj


def matches(obj: Mapping[str, Any], selector: Mapping[str, str] | None) -> bool:
    """An equality label selector, as the API server applies ``labelSelector=k=v,...``."""
    if not selector:
        return True
    labels = (obj.get("metadata") or {}).get("labels") or {}
    return all(labels.get(k) == v for k, v in selector.items())


def _key(obj: Mapping[str, Any]) -> Key:
    meta = obj.get("metadata") or {}
    return meta.get("namespace") or "", meta.get("name", "")


def _version(obj: Mapping[str, Any]) -> str:
    return str((obj.get("metadata") or {}).get("resourceVersion") or "")


def _not_older(new: str, old: str) -> bool:
    """resourceVersions are etcd revisions in practice; anything else cannot be ordered."""
    if new.isdigit() and old.isdigit():
        return int(new) >= int(old)
    return True


class Informer:
    """One kind's list+watch cache; see the module docstring."""

    def __init__(
        self,
        source: WatchSource,
        path: str,
        *,
        selector: Mapping[str, str] | None = None,
        trim: Trim = trim_metadata,
        on_event: OnEvent | None = None,
        name: str = "",
        kind: str = "",
        on_restart: OnRestart | None = None,
    ) -> None:
        self.source = source
        self.path = path
        self.selector = dict(selector or {})
        self.trim = trim
        self.on_event = on_event
        self.name = name or path
        self.kind = kind or self.name
        self.on_restart = on_restart
        self.synced = threading.Event()
        self.lists = 0  # how many times the whole kind was listed (1 + re-lists)
        self._objects: dict[Key, Obj] = {}
        self._deleted: dict[Key, str] = {}  # tombstones: a late write must not resurrect
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ reads
    def list(
        self, namespace: str | None = None, selector: Mapping[str, str] | None = None
    ) -> list[Obj]:
        """The stored objects of ``namespace`` (None: all) that match ``selector``."""
        with self._lock:
            objs = list(self._objects.values())
        return [
            o
            for o in objs
            if (namespace is None or _key(o)[0] == namespace) and matches(o, selector)
        ]

    def size(self) -> int:
        """How many objects the store holds."""
        return len(self._objects)

    # ------------------------------------------------------------------ our own writes
    def put(self, obj: Obj) -> None:
        """An object this process just wrote (as the API server returned it)."""
        if not matches(obj, self.selector):
            return
        key, version = _key(obj), _version(obj)
        with self._lock:
            old = self._objects.get(key)
            gone = self._deleted.get(key)
            if old is not None and not _not_older(version, _version(old)):
                return
            if gone is not None and not (
                version.isdigit() and gone.isdigit() and int(version) > int(gone)
            ):
                return
            self._deleted.pop(key, None)
            self._objects[key] = self.trim(obj)

    def drop(self, namespace: str, name: str) -> None:
        """An object this process just deleted."""
        with self._lock:
            old = self._objects.pop((namespace, name), None)
            if old is not None:
                self._bury((namespace, name), _version(old))

    # ------------------------------------------------------------------ the watch
    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"informer {self.name}", daemon=True
            )
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        version: str | None = None
        backoff = 0.5
        while not self._stop.is_set():
            try:
                if version is None:
                    version = self._relist()
                version = self._watch(version)
                backoff = 0.5
            except WatchExpired:
                log.info("Watch of %s expired; listing again", self.name)
                self._restarted("expired")
                version = None
            except DependencyUnavailable as exc:
                log.warning("Watch of %s failed (%s); retrying in %.1fs", self.name, exc, backoff)
                self._restarted("error")
                self._stop.wait(backoff)
                backoff = min(backoff * 2, MAX_BACKOFF_SECONDS)
            except Exception:  # a bug must not end the cache silently: log, list again
                log.exception("Watch of %s broke; listing again", self.name)
                self._restarted("unexpected")
                version = None
                self._stop.wait(backoff)
                backoff = min(backoff * 2, MAX_BACKOFF_SECONDS)

    def _restarted(self, reason: str) -> None:
        if self.on_restart is not None:
            self.on_restart(self.kind, reason)

    def _relist(self) -> str:
        items, version = self.source.list_versioned(self.path, self.selector or None)
        fresh = {_key(o): self.trim(o) for o in items}
        with self._lock:
            before, self._objects = self._objects, fresh
            self._deleted.clear()
        self.lists += 1
        self.synced.set()
        for key, obj in fresh.items():
            old = before.get(key)
            if old is None or _version(old) != _version(obj):
                self._notify("ADDED" if old is None else "MODIFIED", obj, old)
        for key, old in before.items():
            if key not in fresh:
                self._notify("DELETED", old, old)
        return version

    def _watch(self, version: str) -> str:
        for event in self.source.watch(self.path, self.selector or None, version, WATCH_SECONDS):
            if self._stop.is_set():
                break
            kind = event.get("type")
            raw = event.get("object") or {}
            if kind == "ERROR":
                if raw.get("code") == 410:
                    raise WatchExpired(raw.get("message", ""))
                raise DependencyUnavailable(f"watch of {self.name}: {raw.get('message', raw)}")
            version = _version(raw) or version
            if kind == "BOOKMARK":
                continue
            self._apply(str(kind), raw)
        return version

    def _apply(self, kind: str, raw: Obj) -> None:
        key = _key(raw)
        obj = self.trim(raw)
        with self._lock:
            old = self._objects.get(key)
            if kind == "DELETED":
                self._objects.pop(key, None)
                self._bury(key, _version(raw))
            else:
                if old is not None and not _not_older(_version(obj), _version(old)):
                    return  # our own write was newer
                self._objects[key] = obj
                self._deleted.pop(key, None)
        self._notify(kind, obj, old)

    def _bury(self, key: Key, version: str) -> None:
        """Remember a deletion (the lock is held)."""
        self._deleted.pop(key, None)
        self._deleted[key] = version
        while len(self._deleted) > MAX_TOMBSTONES:
            del self._deleted[next(iter(self._deleted))]

    def _notify(self, kind: str, obj: Obj, old: Obj | None) -> None:
        if self.on_event is None:
            return
        try:
            self.on_event(kind, obj, old)
        except Exception:  # the cache stays right whatever a listener does
            log.exception("Listener of %s failed on %s", self.name, kind)
