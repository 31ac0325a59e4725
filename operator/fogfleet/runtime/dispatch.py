"""The controller runtime the kopf handlers call: one object per operator process.

It owns the worker threads (reconciles and the GA run there, never on the event loop), the
per-fleet queue (serialisation + debouncing) and the change filters that decide which watch
events matter: a SoftwareModule or ComputeNode whose ``generation`` changed, a Node whose
health or allocatable changed, a fleet Deployment whose rollout moved.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from fogfleet.api.labels import LABEL_FLEET, LABEL_INSTANCE
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.clusters import delete_remote, sweep_orphans
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.measure.links import LinkDeps, measure_links
from fogfleet.controllers.measure.observed import ObservedDeps, observe
from fogfleet.controllers.measure.usage import reconcile_usage
from fogfleet.controllers.module.scaling import reconcile_scaling
from fogfleet.controllers.outcome import Outcome
from fogfleet.controllers.stamp import node_signature, pools_signature
from fogfleet.controllers.state import FleetKey, FleetState
from fogfleet.controllers.status import pod_ready
from fogfleet.errors import FogfleetError
from fogfleet.render.deployments import hash_annotation, label_value
from fogfleet.runtime.explanations import Explainer
from fogfleet.runtime.queue import ReconcileQueue
from fogfleet.snapshot.objects import profile_corrections

__all__ = ["Runtime", "Stopping"]

log = logging.getLogger(__name__)
T = TypeVar("T")
# a rollout event's reconcile is a cheap status refresh (controllers/stamp.py): no need to wait
ROLLOUT_QUIET_SECONDS = 0.5
# While more modules than this are still rolling out, a stream of Pod events refreshes the
# fleet's status at most every ROLLOUT_BUSY_MAX_WAIT_SECONDS instead of the queue's max_wait:
# the status then says "waiting for 300" a little later, and the refreshes stop competing with
# the control plane for CPU; the last modules still get the short wait (Ready follows the
# last pod within ROLLOUT_QUIET_SECONDS plus one refresh), and so does a rollout that should
# end within that cap at its pace (at 1000 robots the last 71 of 8000 pods started within one
# 5 s wait, and Ready came up to 5 s after them).
ROLLOUT_BUSY_MODULES = 20
ROLLOUT_BUSY_MAX_WAIT_SECONDS = 5.0
# a reconcile or usage pass slower than this is logged at INFO (the others at DEBUG)
SLOW_SECONDS = 1.0
Obj = dict[str, Any]


class Stopping(Exception):
    """The operator is stopping (or lost its Lease): the call was not made. The next leader
    reconciles every fleet when it starts (kopf's resume handler)."""


class Runtime:
    def __init__(self, deps: Deps, *, workers: int = 4, debounce: float = 2.0) -> None:
        self.deps = deps
        self.executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="fogfleet")
        self.closed = False
        self.queue = ReconcileQueue(
            self._run,
            debounce=debounce,
            retry=deps.retry_seconds,
            on_error=lambda key, reason: deps.metrics.count_error(key[1], reason),
            metrics=deps.metrics,
        )
        self.store = deps.store  # every fleet's state (its rollout progress among it)
        self.explainer = Explainer(deps.kube, self.store)  # ExplanationRequests
        # the change filters: what was last seen of each related object
        self._generations: dict[tuple[str, str, str], Any] = {}
        self._nodes: dict[str, tuple[Any, ...]] = {}
        # shared modules with spec.scaling, by (namespace, name): the scaling loop's work list
        self.scaled: dict[tuple[str, str], Obj] = {}
        self._loops: list[asyncio.Task[None]] = []
        self._usage_due = asyncio.Event()
        self._monitoring_seen = deps.monitoring.transitions

    # ------------------------------------------------------------------ periodic work
    # Our own loops instead of kopf timers: a kopf timer puts a finalizer on every object it
    # serves, which leaves namespaces Terminating forever once the operator is gone. Owner
    # references already clean up what fleets create, so fogfleet needs no finalizer at all.

    def start_periodic(
        self, drift_seconds: float, scaling: Any = None, links: Any = None, observed: Any = None
    ) -> None:
        """Re-check every known fleet each `drift_seconds`; decide scaling each period; measure
        the robots' links and the modules' cycles each period; start the watch caches (their
        Pod events re-check fleets, see :meth:`pod_event`)."""
        if self.deps.watches is not None:
            loop = asyncio.get_running_loop()

            def on_pod(kind: str, pod: Obj, old: Obj | None) -> None:
                loop.call_soon_threadsafe(self.pod_event, kind, pod, old)

            def on_deployment(kind: str, dep: Obj, old: Obj | None) -> None:
                loop.call_soon_threadsafe(self.deployment_event, dep, kind, old)

            def on_node(kind: str, node: Obj, old: Obj | None) -> None:
                # most Node events are kubelet heartbeats: dropped here, off the event loop
                if kind == "DELETED" or old is None or node_signature(node) != node_signature(old):
                    loop.call_soon_threadsafe(self.node_event, node, kind)

            def on_module(kind: str, module: Obj, old: Obj | None) -> None:
                loop.call_soon_threadsafe(self.module_event, module, kind)

            def on_compute_node(kind: str, cn: Obj, old: Obj | None) -> None:
                loop.call_soon_threadsafe(self.compute_node_event, cn, kind)

            # one watch per kind: these caches report the kinds kopf then does not watch
            self.deps.watches.start(on_pod, on_deployment, on_node, on_module, on_compute_node)
        self._loops.append(asyncio.create_task(self._drift(drift_seconds), name="fogfleet-drift"))
        self._loops.append(asyncio.create_task(self._usage(), name="fogfleet-usage"))
        self.usage_changed()
        if scaling is not None:
            self._loops.append(asyncio.create_task(self._scaling(scaling), name="fogfleet-scaling"))
        if links is not None:
            self._loops.append(asyncio.create_task(self._links(links), name="fogfleet-links"))
        if observed is not None:
            self._loops.append(
                asyncio.create_task(self._observed(observed), name="fogfleet-observed")
            )

    async def _drift(self, seconds: float) -> None:
        while True:
            await asyncio.sleep(seconds)
            for key in sorted(self.store.fleets()):
                self.queue.schedule_debounced(key)
            self.usage_changed()

    def usage_changed(self) -> None:
        """Plans or nodes changed: refresh the usage status of modules and ComputeNodes soon
        (one pass for any burst of changes)."""
        self._usage_due.set()

    async def _usage(self) -> None:
        while True:
            await self._usage_due.wait()
            await asyncio.sleep(self.queue.debounce)
            self._usage_due.clear()
            t0 = time.perf_counter()
            try:
                await self.call(reconcile_usage, self.deps)
                if self.deps.hub is not None:  # works of fleets deleted while we were away
                    await self.call(self._sweep_orphans)
            except FogfleetError as exc:  # the next change or drift tick retries
                log.warning("Updating the usage status of modules and nodes failed: %s", exc)
            took = time.perf_counter() - t0
            if took > SLOW_SECONDS:
                log.info("The usage pass over modules and nodes took %.0f ms", took * 1e3)

    def _sweep_orphans(self) -> int:
        return sweep_orphans(self.deps, self.deps.kube.list_fleets(None), time.time())

    async def _scaling(self, scaling: Any) -> None:
        while True:
            await asyncio.sleep(scaling.period_seconds)
            for key, body in sorted(self.scaled.items()):
                try:
                    await self.call(reconcile_scaling, dict(body), scaling, time.time())
                except FogfleetError as exc:  # said in the module's conditions; retried next time
                    log.warning("Scaling SoftwareModule %s/%s failed: %s", *key, exc)
            self._monitoring_moved()

    async def _links(self, links: LinkDeps) -> None:
        """Measure the links every period; reconcile the fleets whose links changed."""
        await self._measuring(links.period_seconds, measure_links, links, "the robots' links")

    async def _observed(self, observed: ObservedDeps) -> None:
        """Read the modules' cycles every period; reconcile the fleets whose drift changed."""
        await self._measuring(observed.period_seconds, observe, observed, "the modules' cycles")

    async def _measuring(
        self, period: float, fn: Callable[..., set[FleetKey]], port: Any, what: str
    ) -> None:
        while True:
            await asyncio.sleep(period)
            try:
                changed = await self.call(fn, self.deps, port, time.time())
            except FogfleetError as exc:  # a bad query or answer: said in the log, retried
                log.warning("Measuring %s failed: %s", what, exc)
                self._monitoring_moved()
                continue
            except Exception:  # a bug: said with its traceback; the loop must not end with it
                log.exception("Measuring %s failed (a bug: please report it)", what)
                continue
            for key in sorted(changed):
                self.queue.schedule_debounced(key)
            if changed:  # the modules' measured miss rates (status.measuredMissRate)
                self.usage_changed()
            self._monitoring_moved()

    def _monitoring_moved(self) -> None:
        """Prometheus stopped or started answering: every fleet's Monitored condition says so
        at its next refresh, which this schedules."""
        seen = self.deps.monitoring.transitions
        if seen == self._monitoring_seen:
            return
        self._monitoring_seen = seen
        log.info(
            "Prometheus %s: re-checking every fleet's Monitored condition",
            "answers again" if self.deps.monitoring.reachable else "does not answer",
        )
        for key in sorted(self.store.fleets()):
            self.queue.schedule_debounced(key)

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on the runtime's threads (``Stopping`` once they are gone)."""
        if self.closed:
            raise Stopping(getattr(fn, "__name__", "a call"))
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.executor, functools.partial(fn, *args))

    async def _run(self, key: FleetKey) -> Outcome | None:
        body = await self.call(self.deps.kube.get_fleet, *key)
        if body is None or (body.get("metadata") or {}).get("deletionTimestamp"):
            self._forget(key)
            return None
        t0, started = time.perf_counter(), time.monotonic()
        state = self.store.state(key)
        before = state.placement
        outcome = await self.call(reconcile, body, self.deps)
        progress = state.rollout
        self._count_rollout(key, outcome.waiting, time.monotonic())
        progress.unsettled = outcome.unsettled
        # a pod shown ready while this ran may be missing from what it read: keep it
        progress.shown_ready = {
            name: at
            for name, at in progress.shown_ready.items()
            if at >= started and name in outcome.unsettled
        }
        took = time.perf_counter() - t0
        log.log(
            logging.INFO if took > SLOW_SECONDS else logging.DEBUG,
            "Reconciled RobotFleet %s/%s in %.0f ms (%s; status written in %.0f ms): %s",
            *key,
            took * 1e3,
            "ready" if outcome.ready else "not ready",
            outcome.status_write_seconds * 1e3,
            outcome.message,
        )
        if state.placement is not before:  # nothing moved: no usage pass
            self.usage_changed()
        if outcome.planned:
            self._neighbours_changed(key, state.claims)
        return outcome

    def _neighbours_changed(self, key: FleetKey, nodes: Iterable[str]) -> None:
        """A fleet's claims on these nodes changed (a new plan, or the fleet went): the other
        fleets on them re-check what is left for them (controllers/fleet/tenancy.py)."""
        for node in sorted(nodes):
            for other in self.store.using_node(node) - {key}:
                self.queue.schedule_debounced(other)

    def _forget(self, key: FleetKey) -> None:
        """The fleet is gone: its state, and its lock and timers in the queue, go; the fleets
        it shared nodes with may use its room."""
        state = self.store.get(key)
        self.store.forget(key)
        if state is not None:
            self._neighbours_changed(key, state.claims)
        self.queue.forget(key)
        self.usage_changed()

    # ------------------------------------------------------------------ fleets
    async def reconcile_fleet(self, namespace: str, name: str) -> Outcome | None:
        return await self.queue.run_now((namespace, name))

    async def delete_fleet(self, namespace: str, name: str) -> None:
        """Delete the fleet's Deployments now (the garbage collector would, via ownerReferences),
        and its ManifestWorks on the OCM hub (which nothing else deletes)."""
        self._forget((namespace, name))
        deps = await self.call(
            self.deps.kube.list_deployments, namespace, {LABEL_FLEET: label_value(name)}
        )
        for dep in deps:
            await self.call(self.deps.kube.delete_deployment, namespace, dep["metadata"]["name"])
        await self.call(delete_remote, self.deps, namespace, label_value(name))
        self.usage_changed()

    # ------------------------------------------------------------------ related objects
    def _changed(
        self, kind: str, body: Mapping[str, Any], event_type: str | None, extra: Any = None
    ) -> bool:
        meta = body.get("metadata") or {}
        key = (kind, meta.get("namespace") or "", meta.get("name", ""))
        if event_type == "DELETED":
            self._generations.pop(key, None)
            return True
        gen = (meta.get("generation"), extra)
        before = self._generations.get(key, "unseen")
        self._generations[key] = gen
        return event_type is not None and before != gen

    def module_event(self, body: Mapping[str, Any], event_type: str | None) -> None:
        meta = body.get("metadata") or {}
        module_key = (meta.get("namespace") or "default", meta.get("name", ""))
        if event_type == "DELETED" or not (body.get("spec") or {}).get("scaling"):
            self.scaled.pop(module_key, None)
        else:
            self.scaled[module_key] = dict(body)
        # the autoscaler's decision (status.scaling.pools) and a profile corrected by what ran
        # (status.profileCorrection) change what fleets place, too
        learnt = tuple(sorted(profile_corrections([body]).items()))
        if self._changed("SoftwareModule", body, event_type, (pools_signature(body), learnt)):
            self.usage_changed()
            meta = body.get("metadata") or {}
            for key in self.store.using_module(
                meta.get("namespace") or "default", meta.get("name", "")
            ):
                self.queue.schedule_debounced(key)

    def compute_node_event(self, body: Mapping[str, Any], event_type: str | None) -> None:
        if self._changed("ComputeNode", body, event_type):
            self.usage_changed()
            for key in self.store.using_compute_node((body.get("metadata") or {}).get("name", "")):
                self.queue.schedule_debounced(key)

    def node_event(self, body: Mapping[str, Any], event_type: str | None) -> None:
        name = (body.get("metadata") or {}).get("name", "")
        if event_type == "DELETED":
            sig: tuple[Any, ...] | None = None
            self._nodes.pop(name, None)
        else:
            sig = node_signature(body)
            before = self._nodes.get(name)
            self._nodes[name] = sig
            if before == sig or (event_type is None and before is None):
                return
        self.usage_changed()
        for key in self.store.using_node(name):
            self.queue.schedule_debounced(key)

    def deployment_event(
        self, body: Mapping[str, Any], kind: str | None = None, old: Mapping[str, Any] | None = None
    ) -> None:
        """A fleet's Deployment changed (rolled out, edited or deleted by hand): re-check that
        fleet. A change of its status alone matters only to a module still rolling out (a
        settled one becomes unsettled through its pods or its spec): kube-controller-manager
        rewrites the status of every Deployment of a large rollout long after its pods run,
        and at 1000 robots those writes alone kept the operator refreshing a Ready fleet
        (~1.4 s of CPU every ~2 s)."""
        if (
            kind not in (None, "DELETED")
            and old is not None
            and _spec_state(body) == _spec_state(old)
        ):
            state = self._state_of(body)
            unsettled = state.rollout.unsettled if state is not None else None
            if unsettled is not None and (body.get("metadata") or {}).get("name") not in unsettled:
                return
        self._rollout_moved(body)

    def pod_event(self, kind: str, pod: Mapping[str, Any], old: Mapping[str, Any] | None) -> None:
        """A fleet's Pod became ready or stopped being ready, or went: re-check the fleet soon,
        so its Ready condition follows its last pod by the short debounce, not by a timer."""
        if kind != "DELETED" and old is not None and _pod_state(pod) == _pod_state(old):
            return
        if log.isEnabledFor(logging.DEBUG):
            meta = pod.get("metadata") or {}
            log.debug(
                "Pod %s/%s %s: ready=%s",
                meta.get("namespace"),
                meta.get("name"),
                kind,
                pod_ready(pod),
            )
        if kind != "DELETED" and self._last_pod_ready(pod):
            return
        self._rollout_moved(pod)

    def _last_pod_ready(self, pod: Mapping[str, Any]) -> bool:
        """Whether this ready Pod is the last its fleet waited for: since the last refresh,
        every module that refresh left rolling out has shown a ready pod. Its fleet is then
        re-checked at once instead of ROLLOUT_QUIET_SECONDS later, and Ready follows the last
        pod by one refresh. A module still moving may also wait for its old pod to go; that
        refresh then finds it unsettled, and the old pod's deletion re-checks it again."""
        state = self._state_of(pod)
        unsettled = state.rollout.unsettled if state is not None else None
        name = ((pod.get("metadata") or {}).get("labels") or {}).get(LABEL_INSTANCE)
        if state is None or not unsettled or name not in unsettled or not pod_ready(pod):
            return False
        shown = state.rollout.shown_ready
        shown[name] = time.monotonic()
        if len(shown) < len(unsettled) or state.references is None:
            return False
        self.queue.schedule(state.key, 0.0)
        return True

    def _state_of(self, obj: Mapping[str, Any]) -> FleetState | None:
        """The state of the fleet a Deployment or Pod belongs to (None: no fleet's, or one
        this process does not know)."""
        key = _fleet_of(obj)
        if key is None:
            return None
        state = self.store.get(key)
        if state is None:  # a fleet name too long for a label value carries a shortened one
            ns, value = key
            known = (k for k in self.store.fleets() if k[0] == ns and label_value(k[1]) == value)
            state = next((self.store.get(k) for k in known), None)
        return state

    def _count_rollout(self, key: FleetKey, waiting: int, now: float) -> None:
        """Record a fleet's modules still rolling out, and when its rollout should end at the
        pace since the last count (inf: no progress, or nothing to compare with)."""
        progress = self.store.state(key).rollout
        before, then = progress.waiting, progress.counted
        progress.waiting, progress.counted = waiting, now
        done = (before - waiting) if before is not None else 0
        if not waiting:
            progress.eta = 0.0
        elif done > 0 and then is not None and now > then:
            progress.eta = waiting / (done / (now - then))
        else:
            progress.eta = math.inf

    def _rollout_moved(self, obj: Mapping[str, Any]) -> None:
        """Re-check the fleet of a Deployment or Pod: a status refresh, ROLLOUT_QUIET_SECONDS
        after the last such event (at most the queue's max_wait into a stream of them)."""
        state = self._state_of(obj)
        if state is not None and state.references is not None:
            progress = state.rollout
            eta = math.inf if progress.eta is None else progress.eta
            busy = (progress.waiting or 0) > ROLLOUT_BUSY_MODULES and (
                eta > ROLLOUT_BUSY_MAX_WAIT_SECONDS
            )
            self.queue.schedule_debounced(
                state.key,
                min(self.queue.debounce, ROLLOUT_QUIET_SECONDS),
                max(ROLLOUT_BUSY_MAX_WAIT_SECONDS, self.queue.max_wait) if busy else None,
            )

    async def close(self) -> None:
        self.closed = True
        if self.deps.watches is not None:
            self.deps.watches.stop()
        for task in self._loops:
            task.cancel()
        await self.queue.close()
        self.executor.shutdown(wait=False, cancel_futures=True)


def _fleet_of(obj: Mapping[str, Any]) -> FleetKey | None:
    """The fleet a Deployment or Pod belongs to, by its fleet label (None: no fleet's)."""
    meta = obj.get("metadata") or {}
    fleet = (meta.get("labels") or {}).get(LABEL_FLEET)
    return (meta.get("namespace") or "default", fleet) if fleet else None


def _spec_state(dep: Mapping[str, Any]) -> tuple[Any, ...]:
    """What of a Deployment is not status: its generation (bumped by any spec change), the
    spec hash fogfleet rendered into it, its labels, and whether it is being deleted."""
    meta = dep.get("metadata") or {}
    return (
        meta.get("generation"),
        hash_annotation(dep),
        tuple(sorted((meta.get("labels") or {}).items())),
        meta.get("deletionTimestamp"),
    )


def _pod_state(pod: Mapping[str, Any]) -> tuple[bool, Any]:
    """What of a Pod the fleet's status reads: ready or not, and on which node."""
    return pod_ready(pod), (pod.get("spec") or {}).get("nodeName")
