"""The runtime's watch-cache hook: Pod changes that matter re-check their fleet, others do not;
the caches start with the runtime's loops and stop with it."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import pytest

from fogfleet.controllers.deps import Deps
from fogfleet.controllers.outcome import Outcome
from fogfleet.controllers.state import References
from fogfleet.runtime.dispatch import Runtime

KEY = ("wh", "fleet")


def pod(ready: bool, node: str = "edge-1", fleet: str = "fleet") -> dict:
    return {
        "metadata": {"name": "p", "namespace": "wh", "labels": {"fogfleet.io/fleet": fleet}},
        "spec": {"nodeName": node},
        "status": {
            "phase": "Running",
            "conditions": [{"type": "Ready", "status": "True" if ready else "False"}],
        },
    }


def record(runtime: Runtime, key, compute_nodes: set[str], modules: set[str]) -> None:
    """What a reconcile records of the fleet's references."""
    runtime.deps.store.state(key).references = References(
        frozenset(compute_nodes), frozenset(compute_nodes), frozenset(modules), False
    )


class FakeWatches:
    def __init__(self) -> None:
        self.listener = None
        self.deployments = None
        self.nodes = None
        self.stopped = False

    def start(
        self, on_pod=None, on_deployment=None, on_node=None, on_module=None, on_compute_node=None
    ) -> None:
        self.listener = on_pod
        self.deployments = on_deployment
        self.nodes = on_node
        self.modules = on_module
        self.compute_nodes = on_compute_node

    def stop(self) -> None:
        self.stopped = True


def rechecked(feed: Callable[[Runtime], None], known: bool = True) -> bool:
    """Whether the fleet KEY (known to the runtime, or not) is due for a re-check once
    ``feed`` has given the runtime its events."""

    async def main() -> bool:
        runtime = Runtime(Deps(kube=object()), debounce=5.0)
        if known:
            record(runtime, KEY, set(), {"m"})
        feed(runtime)
        pending = KEY in runtime.queue.pending()
        await runtime.close()
        return pending

    return asyncio.run(main())


def scheduled_after(events: list[tuple[str, dict, dict | None]], known: bool = True) -> bool:
    def feed(runtime: Runtime) -> None:
        for kind, new, old in events:
            runtime.pod_event(kind, new, old)

    return rechecked(feed, known)


def test_a_pod_turning_ready_moving_or_going_rechecks_its_fleet():
    assert scheduled_after([("MODIFIED", pod(True), pod(False))])
    assert scheduled_after([("MODIFIED", pod(True, "edge-2"), pod(True))])
    assert scheduled_after([("DELETED", pod(True), pod(True))])
    assert scheduled_after([("ADDED", pod(False), None)])


def test_other_pod_changes_and_unknown_fleets_do_not():
    assert not scheduled_after([("MODIFIED", pod(True), pod(True))])
    assert not scheduled_after([("MODIFIED", pod(True), pod(False))], known=False)
    assert not scheduled_after([("MODIFIED", pod(True, fleet="other"), pod(False))])


@pytest.mark.parametrize("listener", ["listener", "deployments"])
def test_the_caches_start_with_the_loops_and_their_events_reach_the_loop(listener):
    watches = FakeWatches()
    assert scheduled_by_a_cache(watches, listener, ("ADDED", pod(True), None))
    assert watches.stopped


def scheduled_by_a_cache(
    watches: FakeWatches, listener: str, event: tuple, prime: Any = None
) -> bool:
    """Whether a cache's ``event`` (heard by ``listener`` on the informer's own thread)
    schedules the fleet that uses edge-1 and module m on the loop; ``prime(runtime)`` first."""

    async def main() -> bool:
        runtime = Runtime(Deps(kube=object(), watches=watches), debounce=5.0)
        record(runtime, KEY, {"edge-1"}, {"m"})
        runtime.start_periodic(3600)
        if prime is not None:
            prime(runtime)
        call = getattr(watches, listener)
        assert call is not None
        t = threading.Thread(target=call, args=event)
        t.start()
        t.join()
        for _ in range(100):
            if KEY in runtime.queue.pending():
                break
            await asyncio.sleep(0.01)
        pending = KEY in runtime.queue.pending()
        await runtime.close()
        return pending

    return asyncio.run(main())


@pytest.mark.parametrize(
    ("listener", "obj"),
    [
        ("modules", {"metadata": {"name": "m", "namespace": KEY[0], "generation": 2}}),
        ("compute_nodes", {"metadata": {"name": "edge-1", "generation": 2}}),
    ],
)
def test_the_caches_report_modules_and_compute_nodes_one_watch_per_kind(listener, obj):
    """With the caches on, kopf does not watch these kinds: the caches' events re-check the
    fleets that use the object."""
    old = {"metadata": {**obj["metadata"], "generation": 1}}
    kind = "SoftwareModule" if listener == "modules" else "ComputeNode"

    def seen_before(runtime: Runtime) -> None:  # what the first listing recorded of it
        runtime._changed(kind, old, None)

    assert scheduled_by_a_cache(FakeWatches(), listener, ("MODIFIED", obj, old), seen_before)


@pytest.mark.parametrize(("waiting", "cap"), [(100, 5.0), (5, None), (0, None)])
def test_a_large_rollout_refreshes_its_status_less_often(waiting: int, cap: float | None):
    """Many modules still rolling out: Pod events wait up to ROLLOUT_BUSY_MAX_WAIT_SECONDS;
    the last few modules get the queue's short cap (Ready follows the last pod quickly)."""
    from fogfleet.runtime import dispatch as rt

    def count(runtime: Runtime) -> None:
        runtime.store.state(KEY).rollout.waiting = waiting

    assert debounce_after_a_pod_event(count) == [(KEY, rt.ROLLOUT_QUIET_SECONDS, cap)]


def debounce_after_a_pod_event(count) -> list[tuple]:
    """How a Pod event of a known fleet schedules its refresh, after ``count(runtime)``
    recorded the fleet's rollout: [(fleet, quiet, max_wait)]."""

    async def main() -> list[tuple]:
        runtime = Runtime(Deps(kube=object()), debounce=5.0)
        record(runtime, KEY, set(), {"m"})
        count(runtime)
        calls: list[tuple] = []
        runtime.queue.schedule_debounced = lambda key, quiet=None, max_wait=None: calls.append(  # type: ignore[method-assign]
            (key, quiet, max_wait)
        )
        runtime.pod_event("MODIFIED", pod(True), pod(False))
        await runtime.close()
        return calls

    return asyncio.run(main())


def node(ready: bool, heartbeat: str) -> dict:
    return {
        "metadata": {"name": "edge-1"},
        "status": {
            "allocatable": {"cpu": "16", "memory": "64Gi"},
            "conditions": [{"type": "Ready", "status": str(ready), "lastHeartbeatTime": heartbeat}],
        },
    }


def test_node_heartbeats_stay_off_the_loop_and_a_node_going_not_ready_rechecks_its_fleets():
    """The Node cache reports Nodes (kopf no longer watches them): a heartbeat changes nothing
    planning reads and is dropped on the watch thread; a Node going NotReady re-checks the
    fleets placing on it."""
    watches = FakeWatches()

    async def main() -> list[bool]:
        runtime = Runtime(Deps(kube=object(), watches=watches), debounce=5.0)
        record(runtime, KEY, {"edge-1"}, {"m"})
        runtime.start_periodic(3600)
        seen = []
        for new, old in [
            (node(True, "t1"), node(True, "t0")),
            (node(False, "t2"), node(True, "t1")),
        ]:
            t = threading.Thread(target=watches.nodes, args=("MODIFIED", new, old))
            t.start()
            t.join()
            for _ in range(20):
                await asyncio.sleep(0.01)
            seen.append(KEY in runtime.queue.pending())
        await runtime.close()
        return seen

    assert asyncio.run(main()) == [False, True]


def test_the_usage_pass_follows_placements_not_every_refresh(kube, deps):
    """A reconcile that leaves every placement as it was does not wake the usage pass (at
    1000 robots it took 1.3 s after each of the rollout's refreshes); one that moves any
    does."""
    fleet = ("warehouse", "warehouse")

    async def main() -> list[bool]:
        runtime = Runtime(deps, debounce=5.0)
        woke = []
        for step in ("plan", "refresh", "pods run", "module moved"):
            if step == "pods run":
                kube.run_pods()
            if step == "module moved":
                state = deps.store.state(fleet)
                state.placement = state.placement[1:]  # as if one had moved
            runtime._usage_due.clear()
            await runtime._run(fleet)
            woke.append(runtime._usage_due.is_set())
        await runtime.close()
        return woke

    assert asyncio.run(main()) == [True, False, False, True]


@pytest.mark.parametrize(
    ("counts", "cap"),
    [
        ([(0.0, 300), (5.0, 100)], None),  # 100 left at 40/s: done within the cap
        ([(0.0, 300), (5.0, 280)], 5.0),  # 280 left at 4/s: a long way to go
        ([(0.0, 100), (5.0, 100)], 5.0),  # no progress: no estimate
        ([(5.0, 100)], 5.0),  # one count: no pace yet
    ],
)
def test_a_rollout_near_its_end_at_its_pace_gets_the_short_wait(counts, cap):
    from fogfleet.runtime import dispatch as rt

    def count(runtime: Runtime) -> None:
        for at, waiting in counts:
            runtime._count_rollout(KEY, waiting, at)

    assert debounce_after_a_pod_event(count) == [(KEY, rt.ROLLOUT_QUIET_SECONDS, cap)]


def deployment(name: str, available: int, generation: int = 1, spec_hash: str = "h1") -> dict:
    return {
        "metadata": {
            "name": name,
            "namespace": "wh",
            "generation": generation,
            "labels": {"fogfleet.io/fleet": "fleet"},
            "annotations": {"fogfleet.io/spec-hash": spec_hash},
        },
        "status": {"observedGeneration": generation, "availableReplicas": available},
    }


def deployment_rechecks(kind: str, new: dict, old: dict | None, unsettled: set[str] | None) -> bool:
    def feed(runtime: Runtime) -> None:
        if unsettled is not None:  # what the fleet's last refresh left rolling out
            runtime.store.state(KEY).rollout.unsettled = frozenset(unsettled)
        runtime.deployment_event(new, kind, old)

    return rechecked(feed)


def test_a_deployment_status_write_rechecks_only_a_module_still_rolling_out():
    status_write = ("MODIFIED", deployment("d-1", 1), deployment("d-1", 0))
    assert deployment_rechecks(*status_write, unsettled={"d-1"})
    # settled: kube-controller-manager catching up with pods that already run changes nothing
    assert not deployment_rechecks(*status_write, unsettled={"d-2"})
    assert not deployment_rechecks(*status_write, unsettled=set())
    # a fleet not refreshed yet, or a kopf event without the old object: re-checked
    assert deployment_rechecks(*status_write, unsettled=None)
    assert deployment_rechecks("MODIFIED", deployment("d-1", 1), None, unsettled=set())


def test_a_deployment_edited_added_or_deleted_rechecks_its_fleet_even_when_settled():
    old = deployment("d-1", 1)
    assert deployment_rechecks("MODIFIED", deployment("d-1", 1, generation=2), old, set())
    assert deployment_rechecks("MODIFIED", deployment("d-1", 1, spec_hash="h2"), old, set())
    assert deployment_rechecks("DELETED", old, old, set())
    assert deployment_rechecks("ADDED", old, None, set())


def module_pod(instance: str, ready: bool) -> dict:
    out = pod(ready)
    out["metadata"]["labels"]["fogfleet.io/instance"] = instance
    return out


def refreshes_after(unsettled: set[str], events: list[tuple[str, bool]]) -> list[tuple]:
    """How each Pod event (instance, ready) of a fleet whose last refresh left ``unsettled``
    rolling out schedules its re-check: ("now",) or ("debounced", quiet)."""

    async def main() -> list[tuple]:
        runtime = Runtime(Deps(kube=object()), debounce=5.0)
        record(runtime, KEY, set(), {"m"})
        runtime.store.state(KEY).rollout.unsettled = frozenset(unsettled)
        calls: list[tuple] = []
        runtime.queue.schedule = lambda key, delay=None: calls.append(
            ("now",) if delay == 0 else ("later", delay)
        )  # type: ignore[method-assign]
        runtime.queue.schedule_debounced = lambda key, quiet=None, max_wait=None: calls.append(  # type: ignore[method-assign]
            ("debounced", quiet)
        )
        for instance, ready in events:
            runtime.pod_event(
                "MODIFIED", module_pod(instance, ready), module_pod(instance, not ready)
            )
        await runtime.close()
        return calls

    return asyncio.run(main())


def test_the_last_pod_a_rollout_waits_for_rechecks_its_fleet_at_once():
    from fogfleet.runtime import dispatch as rt

    quiet = ("debounced", rt.ROLLOUT_QUIET_SECONDS)
    # d-1 and d-2 were rolling out: the first ready pod waits for more, the second is the last
    assert refreshes_after({"d-1", "d-2"}, [("d-1", True), ("d-2", True)]) == [quiet, ("now",)]
    # the same module twice, a settled module's pod, a pod going unready: not the last
    assert refreshes_after({"d-1", "d-2"}, [("d-1", True), ("d-3", True), ("d-2", False)]) == [
        quiet,
        quiet,
        quiet,
    ]
    # nothing was rolling out (or no refresh yet): every event takes the short wait
    assert refreshes_after(set(), [("d-1", True)]) == [quiet]


def test_a_refresh_keeps_the_ready_pods_shown_while_it_ran():
    """A pod shown ready during a refresh may be missing from what the refresh read: it still
    counts towards the last pod afterwards; one shown before the refresh began does not."""

    async def main() -> set[str]:
        runtime = Runtime(Deps(kube=SimpleNamespace(get_fleet=None)), debounce=5.0)
        record(runtime, KEY, set(), {"m"})
        runtime.store.state(KEY).rollout.unsettled = frozenset({"d-1", "d-2", "d-3"})
        runtime.pod_event("MODIFIED", module_pod("d-1", True), module_pod("d-1", False))
        answers = iter(
            [
                {"metadata": {"name": "fleet", "namespace": "wh"}},  # the fleet, read
                Outcome(unsettled=frozenset({"d-1", "d-2", "d-3"})),  # its refresh
            ]
        )

        async def call(fn, *args):
            answer = next(answers)
            if isinstance(answer, Outcome):  # the refresh runs: d-2 turns ready meanwhile
                runtime.pod_event("MODIFIED", module_pod("d-2", True), module_pod("d-2", False))
            return answer

        runtime.call = call  # type: ignore[method-assign]
        await runtime._run(KEY)
        kept = set(runtime.store.state(KEY).rollout.shown_ready)
        await runtime.close()
        return kept

    assert asyncio.run(main()) == {"d-2"}
