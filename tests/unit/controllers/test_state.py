"""The store of every fleet's state: one delete forgets a fleet; references find fleets."""

from __future__ import annotations

from fogfleet.controllers.state import FleetStore, References

A, B, SELECT = ("ns", "a"), ("ns", "b"), ("other", "selector")


def _store() -> FleetStore:
    store = FleetStore()
    store.state(A).references = References(
        frozenset({"edge-1"}), frozenset({"edge-1", "node-x"}), frozenset({"nav"}), False
    )
    store.state(B).references = References(
        frozenset({"edge-2"}), frozenset({"edge-2"}), frozenset({"nav", "slam"}), False
    )
    store.state(SELECT).references = References(modules=frozenset({"nav"}), selector=True)
    store.state(("ns", "unrecorded"))  # seen, but no reconcile recorded its references yet
    return store


def test_references_find_the_fleets_that_use_an_object() -> None:
    store = _store()
    assert store.fleets() == {A, B, SELECT}
    assert store.using_compute_node("edge-1") == {A, SELECT}  # a selector uses every node
    assert store.using_node("node-x") == {A, SELECT}
    assert store.using_module("ns", "nav") == {A, B}  # modules are namespaced
    assert store.using_module("ns", "slam") == {B}


def test_forgetting_a_fleet_is_one_delete() -> None:
    store = _store()
    state = store.state(A)
    state.links.robots["robot-1"] = object()  # type: ignore[assignment]
    store.forget(A)
    assert store.get(A) is None and A not in store.fleets()
    assert store.using_compute_node("edge-1") == {SELECT}
    assert store.state(A).links.robots == {}  # seen again: a fresh state
