"""The one apply engine (``controllers.fleet.engine.sync``): what it writes, keeps and prunes."""

from __future__ import annotations

from typing import Any

from fogfleet.controllers.fleet.engine import Kind, sync
from fogfleet.render.deployments import with_spec_hash

Obj = dict[str, Any]


def _obj(name: str, value: int) -> Obj:
    body = {"metadata": {"name": name, "namespace": "ns"}, "spec": {"value": value}}
    return with_spec_hash(body)


class Recorder:
    def __init__(self) -> None:
        self.applied: list[str] = []
        self.deleted: list[str] = []

    def apply(self, body: Obj) -> Obj:
        self.applied.append(body["metadata"]["name"])
        return {**body, "spec": {**body["spec"], "clusterIP": "198.19.0.1"}}

    def delete(self, namespace: str, name: str) -> None:
        self.deleted.append(f"{namespace}/{name}")


def test_only_what_changed_is_written_and_only_what_is_unwanted_and_not_kept_is_pruned() -> None:
    api = Recorder()
    there = [_obj("same", 1), _obj("changed", 1), _obj("stale", 1), _obj("held", 1)]
    desired = [_obj("same", 1), _obj("changed", 2), _obj("new", 1)]
    held = lambda obj: obj["metadata"]["name"] == "held"  # noqa: E731
    synced = sync(Kind(api.apply, api.delete), "ns", desired, there, 2, keep=held)
    assert sorted(api.applied) == ["changed", "new"]
    assert api.deleted == ["ns/stale"]
    assert (synced.applied, synced.pruned) == (2, 1)
    assert synced.stored["same"] is not None and "clusterIP" not in synced.stored["same"]["spec"]
    assert synced.stored["new"]["spec"]["clusterIP"] == "198.19.0.1"  # as the API server stored it


def test_an_unchanged_object_that_is_not_complete_is_applied_again() -> None:
    """A Service written before its cluster IP was allocated is applied until it has one."""
    api = Recorder()
    has_ip = lambda obj: bool(obj["spec"].get("clusterIP"))  # noqa: E731
    kind = Kind(api.apply, api.delete, complete=has_ip)
    synced = sync(kind, "ns", [_obj("svc", 1)], [_obj("svc", 1)], 1)
    assert api.applied == ["svc"] and synced.stored["svc"]["spec"]["clusterIP"]
    stored = _obj("svc", 1)  # as written, then given its address by the API server
    stored["spec"]["clusterIP"] = "198.19.0.1"
    sync(kind, "ns", [_obj("svc", 1)], [stored], 1)
    assert api.applied == ["svc"]
