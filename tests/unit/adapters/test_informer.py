"""The watch-fed cache against a scripted API server: list, watch, re-list, our own writes."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Mapping

import pytest

from fogfleet.adapters.informer import Informer, WatchExpired, matches
from fogfleet.errors import DependencyUnavailable

Obj = dict


def pod(name: str, rv: int, ns: str = "a", **labels: str) -> Obj:
    return {
        "metadata": {
            "name": name,
            "namespace": ns,
            "resourceVersion": str(rv),
            "labels": labels,
            "managedFields": [{"manager": "kubectl"}],
        }
    }


class Script:
    """A WatchSource: each list returns the next listing, each watch the next event batch
    (a batch may be an exception to raise). Records the versions watched from."""

    def __init__(self, lists: list[tuple[list[Obj], str]], watches: list) -> None:
        self.lists = lists
        self.watches = watches
        self.watched_from: list[str] = []
        self.done = threading.Event()

    def list_versioned(self, path: str, selector: Mapping[str, str] | None) -> tuple[list, str]:
        items, version = self.lists.pop(0)
        return [i for i in items if matches(i, selector)], version

    def watch(self, path: str, selector, version: str, seconds: int) -> Iterator[Obj]:
        self.watched_from.append(version)
        if not self.watches:
            self.done.set()
            time.sleep(60)  # a quiet watch
            return
        batch = self.watches.pop(0)
        if isinstance(batch, Exception):
            raise batch
        yield from batch


def wait_until(check, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def started(script: Script, **kwargs) -> tuple[Informer, list]:
    events: list = []
    informer = Informer(
        script, "/api/v1/pods", on_event=lambda k, o, old: events.append((k, o, old)), **kwargs
    )
    informer.start()
    wait_until(script.done.is_set)
    informer.stop()
    return informer, events


def names(informer: Informer, ns: str | None = None, **selector: str) -> list[str]:
    return sorted(o["metadata"]["name"] for o in informer.list(ns, selector or None))


def test_list_then_watch_events_keep_the_store_and_bookmarks_move_the_version():
    script = Script(
        [([pod("p1", 1), pod("p2", 2, ns="b")], "10")],
        [
            [
                {"type": "ADDED", "object": pod("p3", 11)},
                {"type": "MODIFIED", "object": pod("p1", 12, ready="yes")},
                {"type": "DELETED", "object": pod("p2", 13, ns="b")},
                {"type": "BOOKMARK", "object": {"metadata": {"resourceVersion": "20"}}},
            ]
        ],
    )
    informer, events = started(script)
    assert informer.synced.is_set() and informer.lists == 1
    assert names(informer) == ["p1", "p3"] and names(informer, "b") == []
    assert names(informer, "a", ready="yes") == ["p1"]
    assert script.watched_from == ["10", "20"]  # the next watch starts at the bookmark
    kinds = [(k, o["metadata"]["name"]) for k, o, _ in events]
    assert kinds == [
        ("ADDED", "p1"),
        ("ADDED", "p2"),
        ("ADDED", "p3"),
        ("MODIFIED", "p1"),
        ("DELETED", "p2"),
    ]
    modified = events[3]
    assert modified[2]["metadata"]["resourceVersion"] == "1"  # the listener sees the old state
    # trimmed on the way in
    assert all("managedFields" not in o["metadata"] for o in informer.list())


def test_gone_relists_and_reports_what_disappeared_meanwhile():
    script = Script(
        [([pod("p1", 1), pod("p2", 2)], "10"), ([pod("p2", 2), pod("p4", 30)], "31")],
        [
            [{"type": "ERROR", "object": {"code": 410, "message": "too old resource version"}}],
        ],
    )
    informer, events = started(script)
    assert informer.lists == 2 and names(informer) == ["p2", "p4"]
    assert script.watched_from == ["10", "31"]
    after = [(k, o["metadata"]["name"]) for k, o, _ in events[2:]]
    assert after == [("ADDED", "p4"), ("DELETED", "p1")]  # p2 unchanged: no event


def test_a_410_from_the_watch_request_also_relists():
    script = Script([([pod("p1", 1)], "10"), ([], "40")], [WatchExpired("gone")])
    informer, _ = started(script)
    assert informer.lists == 2 and names(informer) == []


def test_a_broken_connection_rewatches_from_the_last_version_without_relisting():
    script = Script(
        [([pod("p1", 1)], "10")],
        [
            [{"type": "ADDED", "object": pod("p2", 15)}],
            DependencyUnavailable("Cannot watch: connection reset"),
        ],
    )
    informer, _ = started(script)
    assert informer.lists == 1 and names(informer) == ["p1", "p2"]
    assert script.watched_from == ["10", "15", "15"]


def test_our_own_write_is_read_back_and_never_replaced_by_an_older_version():
    script = Script([([pod("p1", 5)], "10")], [])
    informer, _ = started(script)
    informer.put(pod("p1", 20, ready="yes"))
    assert names(informer, ready="yes") == ["p1"]
    informer._apply("MODIFIED", pod("p1", 18))  # a late event from before our write
    assert names(informer, ready="yes") == ["p1"]
    informer._apply("MODIFIED", pod("p1", 21))  # a newer one wins
    assert names(informer, ready="yes") == []
    informer.put(pod("p1", 19, ready="yes"))  # a write older than what we hold is ignored
    assert names(informer, ready="yes") == []


def test_a_deleted_object_is_not_brought_back_by_a_late_write():
    script = Script([([pod("p1", 5)], "10")], [])
    informer, _ = started(script)
    informer._apply("DELETED", pod("p1", 30))
    informer.put(pod("p1", 25))
    assert names(informer) == []
    informer.put(pod("p1", 31))  # created again after the deletion
    assert names(informer) == ["p1"]
    informer.drop("a", "p1")
    informer.put(pod("p1", 31))
    assert names(informer) == []


def test_objects_outside_the_selector_are_not_cached():
    script = Script([([pod("p1", 1, managed="yes"), pod("p2", 2)], "10")], [])
    informer, _ = started(script, selector={"managed": "yes"})
    informer.put(pod("p3", 11))
    assert names(informer) == ["p1"]


def test_a_failing_listener_does_not_stop_the_cache():
    script = Script([([pod("p1", 1)], "10")], [[{"type": "ADDED", "object": pod("p2", 11)}]])

    def boom(*_):
        raise RuntimeError("listener bug")

    informer = Informer(script, "/api/v1/pods", on_event=boom)
    informer.start()
    wait_until(script.done.is_set)
    informer.stop()
    assert names(informer) == ["p1", "p2"]


@pytest.mark.parametrize(
    ("labels", "selector", "expected"),
    [({"a": "1", "b": "2"}, {"a": "1"}, True), ({"a": "1"}, {"a": "2"}, False), ({}, None, True)],
)
def test_matches_is_an_equality_selector(labels, selector, expected):
    assert matches({"metadata": {"labels": labels}}, selector) is expected
