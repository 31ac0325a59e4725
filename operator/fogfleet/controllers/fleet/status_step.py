"""The status step: the one writer of a RobotFleet's status.

Compute, compare, write on change (as cert-manager's readiness controller does): the status is
built as its model (``fleet_status``), compared with the one the fleet has apart from
timestamps, and patched once when it differs; the Events that go with the change follow. A
fleet whose plan is held (paused, waiting for profiles, invalid) gets its conditions the same
way (``hold``).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from fogfleet.api.labels import LABEL_FLEET
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.observe import FleetInputs, FleetObject
from fogfleet.controllers.fleet.status import (
    fleet_status,
    held_status,
    placement_entries,
    running_wire,
)
from fogfleet.controllers.measure.drift_report import drift_events, drift_report
from fogfleet.controllers.measure.links import link_events, link_report, takeover_events
from fogfleet.controllers.outcome import Outcome
from fogfleet.controllers.state import FleetState, Rendered
from fogfleet.controllers.status import (
    changed_parts,
    condition,
    find_condition,
    rollout,
    same_status,
)
from fogfleet.errors import DanglingReference, Infeasible, InvalidSpec
from fogfleet.render.deployments import label_value

__all__ = [
    "hold",
    "keep_last_plan",
    "paused",
    "refresh",
    "report_failure",
    "waiting_for_profiles",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
RUNS_ITS_LAST_PLAN = "the fleet runs its last plan until a new one fits"


def refresh(
    deps: Deps,
    state: FleetState,
    inputs: FleetInputs,
    rendered: Rendered,
    planned: bool,
    replan_failed: InvalidSpec | None = None,
) -> tuple[Outcome, Obj]:
    """The status from where the rendered Deployments stand (one patch, only if it changed),
    and the fleet's status now. ``replan_failed``: why a new plan could not be made, while
    the fleet runs ``rendered`` (Ready and Scheduled False say it, with a PlanFailed Event
    when it changes; Degraded, links and drift go on describing what runs)."""
    obj = inputs.obj
    ns, name = obj.key
    pods = deps.kube.list_pods(ns, {LABEL_FLEET: label_value(name)})
    roll = rollout(rendered.desired, inputs.deployments, pods)
    placement = placement_entries(
        rendered.problem, rendered.desired, roll, rendered.plan, rendered.baseline
    )
    if state.placement != placement:  # the usage pass reads it (usage.py)
        state.placement = placement  # replaced only when it changed
    links = link_report(
        state.links.watch, state.links.robots, state.links.standbys_active, state.links.takeovers
    )
    drift = drift_report(state.drift.watch, state.drift.modules, state.drift.onboard)
    held = None
    if replan_failed is not None:
        held = (replan_failed.reason, f"{replan_failed}; {RUNS_ITS_LAST_PLAN}")
    status = running_wire(
        fleet_status(
            inputs.fleet,
            rendered,
            placement,
            roll,
            obj.generation,
            obj.old_status,
            links,
            drift,
            state.shared if not rendered.baseline else None,
            deps.monitoring.condition(obj.generation),
            held,
        )
    )
    ready = not roll.waiting and not roll.moving and not rendered.stranded and held is None
    events = [
        *link_events(obj.old_status.get("links") or [], links.entries),
        *drift_events(obj.old_status.get("measured") or [], drift.entries, drift.notes),
        *takeover_events(obj.old_status.get("fallbacks") or [], status.get("fallbacks") or []),
    ]
    if held is not None and _condition_message(obj.old_status, "Scheduled") != held[1]:
        events.append(("Warning", "PlanFailed", held[1]))
        log.warning("Could not re-plan RobotFleet %s/%s: %s", ns, name, held[1])
    written = _write(deps, obj, status, events)
    if written is not None and ready != _is_ready(obj.old_status):
        log.info(
            "RobotFleet %s/%s is %sReady: %s",
            ns,
            name,
            "" if ready else "not ",
            _condition_message(status, "Ready"),
        )
    outcome = Outcome(
        planned=planned,
        ready=ready,
        # a fleet held on its last plan plans again when its inputs change (events, the drift
        # timer), not every few seconds: each try builds the whole problem
        requeue_after=None if ready or held is not None else deps.requeue_seconds,
        message=_condition_message(status, "Ready"),
        waiting=len(roll.waiting) + len(roll.moving),
        unsettled=frozenset(roll.waiting).union(roll.moving),
        status_write_seconds=written or 0.0,
    )
    return outcome, (status if written is not None else obj.old_status)


def keep_last_plan(
    deps: Deps, state: FleetState, inputs: FleetInputs, last: Rendered, exc: InvalidSpec
) -> Outcome:
    """A re-plan of a running fleet found no placement (a changed spec, learnt profiles that
    no longer fit, a node gone): nothing that runs is touched, and the status goes on saying
    where the fleet stands on its last plan (rollout, links, standbys, drift) with Ready and
    Scheduled False and why; each pass tries to plan again."""
    deps.metrics.count_error(inputs.obj.key[1], exc.reason)
    state.rendered = last  # its stamp is not the inputs': the next pass plans again
    outcome, _ = refresh(deps, state, inputs, last, planned=False, replan_failed=exc)
    return outcome


def hold(
    deps: Deps,
    obj: FleetObject,
    conditions: list[Obj],
    keep: str = "",
    event: tuple[str, str, str] | None = None,
) -> bool:
    """Write the held fleet's conditions (nothing that runs is touched); ``event`` goes with a
    change; the Monitored condition goes with every hold. Returns whether the status changed."""
    conditions = [*conditions, deps.monitoring.condition(obj.generation)]
    status = held_status(obj.generation, obj.old_status, conditions, keep)
    return _write(deps, obj, status, [event] if event else []) is not None


def paused(deps: Deps, obj: FleetObject) -> Outcome:
    message = "spec.paused is true: nothing is planned or changed until it is false"
    hold(deps, obj, [condition("Scheduled", False, "Paused", message, obj.generation)])
    return Outcome(message="paused")


def report_failure(deps: Deps, obj: FleetObject, exc: InvalidSpec) -> None:
    """Ready=False with the precise reason, one Event; nothing that runs is touched."""
    ns, name = obj.key
    deps.metrics.count_error(name, exc.reason)
    msg = str(exc)
    if isinstance(exc, DanglingReference):
        msg += " (create it, or fix the reference)"
    conditions = [
        condition("Ready", False, exc.reason, msg, obj.generation),
        condition("Scheduled", False, exc.reason, msg, obj.generation),
    ]
    reason = "PlanFailed" if isinstance(exc, Infeasible) else exc.reason
    hold(deps, obj, conditions, keep="Degraded", event=("Warning", reason, msg))
    log.warning("Failed to reconcile RobotFleet %s/%s: %s", ns, name, msg)


def report_bug(deps: Deps, obj: FleetObject, exc: Exception) -> None:
    """An unexpected error (a bug) says so in Ready and Scheduled, with one Event, instead of
    leaving the last reason standing; nothing that runs is touched. Best effort: the error
    itself goes on to the queue's retry and log."""
    msg = (
        f"the operator failed on this fleet: {type(exc).__name__}: {exc} (a bug: please report "
        "it with the operator's log); it retries with a backoff, what runs stays as it is"
    )
    conditions = [
        condition("Ready", False, "ReconcileError", msg, obj.generation),
        condition("Scheduled", False, "ReconcileError", msg, obj.generation),
    ]
    try:
        hold(deps, obj, conditions, keep="Degraded", event=("Warning", "ReconcileError", msg))
    except Exception:  # the cluster did not take it: the log and the retry still say it
        log.warning("RobotFleet %s/%s: could not write the error to its status", *obj.key)


def _write(
    deps: Deps, obj: FleetObject, status: Obj, events: list[tuple[str, str, str]]
) -> float | None:
    """Patch the parts of ``status`` that differ from the fleet's, then post ``events``; the
    seconds the patch took (None: nothing changed)."""
    deps.metrics.observe_fleet_status(*obj.key, status)
    if same_status(obj.old_status, status):
        return None
    t0 = time.perf_counter()
    deps.kube.patch_fleet_status(*obj.key, changed_parts(obj.old_status, status))
    took = time.perf_counter() - t0
    for kind, reason, message in events:
        deps.kube.emit_event(obj.involved, kind, reason, message)
    return took


def _is_ready(status: Obj) -> bool:
    ready = find_condition(status.get("conditions"), "Ready")
    return ready is not None and ready.get("status") == "True"


def _condition_message(status: Obj, type_: str) -> str:
    found = find_condition(status.get("conditions"), type_)
    return "" if found is None else str(found.get("message"))


def waiting_for_profiles(deps: Deps, obj: FleetObject, message: str, failed: bool) -> None:
    """Ready and Scheduled False while the fleet waits for profiles (nothing that runs is
    touched); an Event when that starts or its reason changes."""
    reason = "ProfilingFailed" if failed else "ProfilingPending"
    conditions = [
        condition("Ready", False, reason, message, obj.generation),
        condition("Scheduled", False, reason, message, obj.generation),
    ]
    was = (find_condition(obj.old_status.get("conditions"), "Ready") or {}).get("reason")
    event = ("Warning" if failed else "Normal", reason, message) if was != reason else None
    if hold(deps, obj, conditions, keep="others", event=event) and event is not None:
        log.info("RobotFleet %s/%s waits for profiles: %s", *obj.key, message)
