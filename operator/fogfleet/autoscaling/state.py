"""The autoscaler's memory across operator restarts: behaviour windows (stabilisation and
policy periods) and the previous rates, as compact JSON in a SoftwareModule annotation."""

from __future__ import annotations

import json
import logging
from typing import Any

from fogfleet.api.labels import ANNOTATION_SCALER_STATE

from .behavior import BehaviorState, Recommendation, ScaleEvent
from .policy import MetricsSnapshot, ScaleDecision, ScalerState

__all__ = ["ANNOTATION_STATE", "dump_state", "load_state"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
ANNOTATION_STATE = ANNOTATION_SCALER_STATE


def dump_state(state: ScalerState) -> str:
    """The behaviour memory and the previous rates as compact JSON (the annotation)."""
    prev = state.previous
    data: Obj = {
        "v": 1,
        "behavior": {
            name: {
                "r": [[round(r.timestamp, 3), r.replicas] for r in s.recommendations],
                "e": [[round(e.timestamp, 3), e.change] for e in s.events],
            }
            for name, s in sorted(state.behavior.items())
        },
    }
    if prev is not None:
        data["prev"] = {
            "t": round(prev.timestamp, 3),
            "p": prev.private_rate,
            "n": prev.normal_rate,
        }
    return json.dumps(data, separators=(",", ":"))


def load_state(text: str | None, last: ScaleDecision | None) -> ScalerState:
    """Inverse of :func:`dump_state`; a missing or unreadable annotation starts afresh."""
    try:
        data = json.loads(text) if text else {}
        behavior = {
            name: BehaviorState(
                tuple(Recommendation(float(t), int(n)) for t, n in s.get("r", [])),
                tuple(ScaleEvent(float(t), int(c)) for t, c in s.get("e", [])),
            )
            for name, s in (data.get("behavior") or {}).items()
        }
        prev = data.get("prev")
        previous = (
            MetricsSnapshot(float(prev["t"]), (), prev.get("p"), prev.get("n")) if prev else None
        )
    except (ValueError, TypeError, KeyError, AttributeError):
        log.warning("Ignored an unreadable %s annotation", ANNOTATION_STATE)
        behavior, previous = {}, None
    return ScalerState(behavior, last, previous)
