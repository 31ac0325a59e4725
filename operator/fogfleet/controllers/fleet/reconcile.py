"""The RobotFleet controller: one level-based ``reconcile(fleet, deps) -> Outcome``, a pipeline of
typed steps:

    observe (FleetInputs) -> plan (Planned) -> render (Deployments) -> apply -> status

Create, update, resume, the drift timer and every debounced trigger (a module, ComputeNode or
Node changed; a Deployment or Pod moved) call the same function. When nothing it reads but the
rollout's progress changed since the last full pass (the stamp, ``stamp.input_stamp``), it only
refreshes the status from the rendered Deployments it kept. Otherwise it plans only when the
planning inputs changed (the decision is kept by fingerprint), keeps running modules in place
unless the new plan is better by the migration margin (``scheduling.decision``), applies with
server-side apply, prunes stale Deployments, and writes the status in one patch. What the pass
leaves in the fleet's ``FleetState`` is all the next one, and the link, drift and usage
passes, read. Invalid input (bad spec, dangling reference, a fleet that cannot fit) touches
nothing that runs: it sets ``Ready=False`` with the reason, posts an Event and re-raises so the
handler can map it. A fleet that runs a plan and then cannot be planned again (a changed spec,
learnt profiles or a lost node that leave no placement) keeps its last plan, and its status
keeps following it (``Ready`` and ``Scheduled`` False say why; Degraded, links and drift stay
current).

Blocking (API calls, the GA): run it in a worker thread (``asyncio.to_thread``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Any

from fogfleet.controllers.deps import Deps
from fogfleet.controllers.fleet.apply import apply_services, apply_step
from fogfleet.controllers.fleet.explain import held_plan
from fogfleet.controllers.fleet.node_events import hosted_modules, node_events
from fogfleet.controllers.fleet.observe import (
    FleetInputs,
    FleetObject,
    Parsed,
    observe,
    parse,
    parse_fleet,
    record_references,
    relisted,
    with_held_now,
)
from fogfleet.controllers.fleet.plan import Planned, plan_step
from fogfleet.controllers.fleet.render import relay_step, render_step, wiring_step
from fogfleet.controllers.fleet.status import plan_events
from fogfleet.controllers.fleet.status_step import (
    keep_last_plan,
    paused,
    refresh,
    report_bug,
    report_failure,
    waiting_for_profiles,
)
from fogfleet.controllers.measure.links import link_watch, takeovers_from_status
from fogfleet.controllers.measure.observed import drift_watch
from fogfleet.controllers.measure.profiling import PROFILING_POLL_SECONDS, profile_first
from fogfleet.controllers.outcome import Outcome
from fogfleet.controllers.stamp import RESYNC_MAX_DEFER_SECONDS, resync_overdue
from fogfleet.controllers.state import FleetState, Rendered
from fogfleet.errors import FogfleetError, Infeasible, InvalidSpec
from fogfleet.snapshot import room_note
from fogfleet.snapshot.clusters import managed_clusters_of
from fogfleet.snapshot.objects import current_placement

__all__ = ["Outcome", "reconcile"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


def reconcile(body: Obj, deps: Deps) -> Outcome:
    """Bring the cluster to the fleet's desired state. See the module docstring."""
    obj = FleetObject.read(body)
    state = deps.store.state(obj.key)
    try:
        fleet = parse_fleet(body)
        record_references(state, fleet)
        if fleet.spec.paused:
            return paused(deps, obj)
        inputs = observe(deps, state, obj, fleet)
        last = state.rendered
        state.rendered = None  # a full pass that fails leaves nothing to reuse
        if last is not None and last.stamp == inputs.stamp:
            outcome, status = _refresh(deps, state, inputs, last)
            if outcome is not None:
                return outcome
            inputs = replace(inputs, obj=replace(obj, old_status=status))
        else:
            log.debug("RobotFleet %s/%s: inputs changed, full reconcile", *obj.key)
        claims, shared = state.claims, state.shared
        try:
            return _full_pass(deps, state, inputs, last)
        except Infeasible as exc:
            if last is None or last.plan is None:
                raise
            state.claims, state.shared = claims, shared  # its pods stay on the last plan
            return keep_last_plan(deps, state, inputs, last, exc)
    except InvalidSpec as exc:
        report_failure(deps, obj, exc)
        raise
    except FogfleetError:  # the cluster or Prometheus did not answer: retried with a backoff
        raise
    except Exception as exc:
        report_bug(deps, obj, exc)
        raise


def _refresh(
    deps: Deps, state: FleetState, inputs: FleetInputs, last: Rendered
) -> tuple[Outcome | None, Obj]:
    """A status refresh from the last render; no outcome when that render is overdue for a
    full pass (the status written stands)."""
    state.rendered = last
    overdue = resync_overdue(last.at, last.seconds, deps.full_reconcile_seconds)
    outcome, status = refresh(deps, state, inputs, last, planned=False)
    if overdue is None or (outcome.waiting and overdue < RESYNC_MAX_DEFER_SECONDS):
        return outcome, status
    state.rendered = None
    log.debug("RobotFleet %s/%s: re-rendering a %.0f s old render", *inputs.obj.key, overdue)
    return None, status


def _full_pass(
    deps: Deps, state: FleetState, inputs: FleetInputs, last: Rendered | None
) -> Outcome:
    started = time.monotonic()
    obj, fleet = inputs.obj, inputs.fleet
    with deps.planning:  # one plan at a time, into what the others claimed (tenancy.py)
        inputs = with_held_now(deps, state, inputs)
        parsed = parse(inputs)
        record_references(state, fleet, parsed.wanted)
        # modules with profiling auto are planned once their profiles are known (issue 10)
        waiting, recorded = profile_first(deps, fleet, parsed.catalog, inputs.raw_modules)
        if waiting:
            waiting_for_profiles(deps, obj, waiting.message, waiting.failed)
            poll = None if waiting.failed else PROFILING_POLL_SECONDS
            return Outcome(requeue_after=poll, message=waiting.message)
        if recorded:  # the rows just written are part of the modules now
            parsed = parse(inputs)
        planned = plan_step(deps, state, inputs, parsed, last)
    unavailable, events = _node_events(state, inputs, parsed, planned)
    objects = wiring_step(inputs, parsed, planned)
    wiring = apply_services(deps, obj.key[0], obj.selector, objects)
    desired = render_step(inputs, parsed, planned, wiring)
    router = deps.hub.router if deps.hub is not None else ""
    objects, desired = relay_step(inputs, planned, objects, wiring, desired, router)
    applied, pruned = apply_step(
        deps,
        *obj.key,
        desired,
        inputs.listed,
        planned.problem,
        planned.stranded,
        objects,
        obj.selector,
        managed_clusters_of(inputs.compute_nodes),
        inputs.hub_error,
    )
    inputs = relisted(deps, state, inputs)  # what we wrote is what the next stamp sees
    rendered = _remember(state, inputs, parsed, planned, desired, started)
    outcome, _ = refresh(deps, state, inputs, rendered, planned.planned)
    decision = planned.decision if planned.planned else None
    if decision is not None:
        events += plan_events(planned.problem, decision, rendered.room)
    for kind, reason, message in events:
        deps.kube.emit_event(obj.involved, kind, reason, message)
    state.unavailable = unavailable  # once its Events are out (a failed pass posts them again)
    migrations = decision.migrations if decision is not None else 0
    return replace(outcome, applied=applied, pruned=pruned, migrations=migrations)


def _node_events(
    state: FleetState, inputs: FleetInputs, parsed: Parsed, planned: Planned
) -> tuple[dict[str, str], list[tuple[str, str, str]]]:
    """The fleet's unavailable nodes now (Kubernetes Node -> why), and NodeUnavailable /
    NodeAvailable for those whose health changed since the last full pass (node_events.py),
    naming the modules bound to them before this pass."""
    problem = planned.problem
    now = {
        n.node_name: parsed.inputs.unavailable[n.name]
        for n in problem.nodes
        if n.name in parsed.inputs.unavailable
    }
    before = state.unavailable
    if now.keys() == before.keys():
        return now, []
    hosted = hosted_modules(problem, current_placement(inputs.deployments))
    waiting = {problem.label(i) for i in planned.stranded}
    for node in sorted(now.keys() - before.keys()):
        log.warning("Node %s of RobotFleet %s/%s is %s", node, *inputs.obj.key, now[node])
    return now, node_events(before, now, hosted, waiting)


def _remember(
    state: FleetState,
    inputs: FleetInputs,
    parsed: Parsed,
    planned: Planned,
    desired: list[Obj],
    started: float,
) -> Rendered:
    """Keep the full pass's result in the fleet's state, for the status refreshes and the
    link and drift passes."""
    done = time.monotonic()
    rendered = Rendered(
        inputs.stamp,
        done,
        done - started,
        planned.problem,
        desired,
        planned.stranded,
        planned.decision,
        planned.baseline,
        measured=inputs.measured,
        room=room_note(planned.problem, inputs.held),
    )
    state.rendered = rendered
    state.live = held_plan(inputs, planned)
    if state.links.takeovers is None:  # after a restart: what the status said they did
        state.links.takeovers = takeovers_from_status(inputs.obj.old_status)
    state.links.watch = link_watch(inputs.fleet, planned.problem, parsed.catalog)
    state.drift.watch = drift_watch(inputs.fleet, planned.problem, parsed.catalog, planned.decision)
    return rendered
