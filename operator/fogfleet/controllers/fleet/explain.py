"""ExplanationRequests (``api/v1alpha1/explanation.py``) answered from the plan the operator
holds: ``kubectl fogfleet why`` without rebuilding the fleet from the API's objects.

A full pass that deployed a plan keeps it in the fleet's state (``held_plan``: the snapshot it
planned from, the problem as planned, the placement deployed). ``answer`` explains a module of
it with the plugin's own code (``snapshot.live.why_of`` and ``why_doc``), so the operator's
answer is the document the plugin would print, and it reads one object: the fleet, for its
measured miss rates, which change between plans. A request the operator cannot answer (no plan
held: not planned yet, planned by kube-scheduler, or in a namespace it does not watch; no such
module) is Failed with the reason, and the plugin explains from the API's objects instead.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from typing import Any

import numpy as np
from pydantic import ValidationError

from fogfleet.adapters.ports import KubePort
from fogfleet.api.kinds import ExplanationFailure, ExplanationPhase
from fogfleet.api.loader import describe_validation_errors
from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.explanation import ExplanationRequest
from fogfleet.controllers.fleet.observe import FleetInputs
from fogfleet.controllers.fleet.plan import Planned
from fogfleet.controllers.state import FleetStore
from fogfleet.domain.problem import freeze
from fogfleet.errors import InvalidSpec
from fogfleet.snapshot import room_note, unavailable_in
from fogfleet.snapshot.live import Live, why_doc, why_of
from fogfleet.snapshot.objects import measured_rates

__all__ = ["REQUEST_TTL_SECONDS", "answer", "held_plan"]

Obj = dict[str, Any]
REQUEST_TTL_SECONDS = 600.0  # an answered request the asker left behind is deleted after this
# the largest explanation written into a status: etcd takes requests up to 1.5 MiB, and a
# module of every robot on a large site (50 instances x 100 nodes x 8 objectives) exceeds it
ANSWER_BYTES = 512 * 1024


def held_plan(inputs: FleetInputs, planned: Planned) -> Live | None:
    """The plan a full pass deployed, as requests are answered from it; None for a
    k8s-default fleet (kube-scheduler binds its pods: the plugin reads where from the status)."""
    if planned.decision is None:
        return None
    placement = freeze(np.asarray(planned.decision.placement, dtype=np.int64).copy())
    # where each instance runs once this plan is out: a move explained costs a migration
    problem = replace(planned.problem, current=placement)
    measured = measured_rates({"status": inputs.obj.old_status}, inputs.raw_modules)
    snapshot = replace(planned.snapshot, measured=measured)
    return Live(snapshot, problem, unavailable_in(snapshot, problem), placement)


def answer(kube: KubePort, store: FleetStore, body: Obj, now: float) -> Obj:
    """The status that answers the request ``body``: Answered with the explanation, or
    Failed with the reason."""
    try:
        request = ExplanationRequest.model_validate(body)
    except ValidationError as exc:  # the CRD's schema admits nothing else: an older CRD
        said = "; ".join(f"{path}: {why}" for path, why in describe_validation_errors(exc))
        return _failed(ExplanationFailure.INVALID_REQUEST, f"invalid request: {said}", now)
    spec = request.spec
    ns = request.metadata.namespace or "default"
    state = store.get((ns, spec.fleet))
    live = state.live if state is not None else None
    if live is None:
        return _failed(
            ExplanationFailure.NO_PLAN_HELD,
            f"the operator holds no plan of RobotFleet {ns}/{spec.fleet}: not planned yet, "
            "placed by kube-scheduler (k8s-default), or in a namespace it does not watch",
            now,
        )
    fleet = kube.get_fleet(ns, spec.fleet)
    if fleet is None:
        return _failed(
            ExplanationFailure.FLEET_NOT_FOUND, f"RobotFleet {ns}/{spec.fleet} not found", now
        )
    # the plan's rates, updated by what the status measured since
    measured = {**live.measured, **measured_rates(fleet, [])}
    live = replace(live, snapshot=replace(live.snapshot, measured=measured))
    try:
        why = why_of(live, spec.module, spec.robot, spec.limit)
    except InvalidSpec as exc:
        return _failed(ExplanationFailure.INVALID_REQUEST, exc.message, now)
    doc = _finite(why_doc(why))
    size = len(json.dumps(doc, separators=(",", ":")))
    if size > ANSWER_BYTES:
        return _failed(
            ExplanationFailure.TOO_LARGE,
            f"the answer would take {size // 1024} KiB, over the {ANSWER_BYTES // 1024} KiB "
            "a request's status holds; ask for one robot (--robot) or fewer (--limit)",
            now,
        )
    return {
        "phase": ExplanationPhase.ANSWERED.value,
        "answeredTime": timestamp(now),
        "planGeneration": live.fleet.metadata.generation,
        "explanation": doc,
        "sharedNodes": room_note(live.problem, live.snapshot.held) or None,
    }


def _failed(reason: ExplanationFailure, message: str, now: float) -> Obj:
    return {
        "phase": ExplanationPhase.FAILED.value,
        "answeredTime": timestamp(now),
        "reason": reason.value,
        "message": message,
    }


def _finite(value: Any) -> Any:
    """``value`` with every NaN or infinite number as null (JSON has neither)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value
