"""The split module's part of ``FOGFLEET_MODULE_SPEC`` (``contract.dnn``), read without pydantic.

The workload image installs fogfleet without its dependencies, so the API's ``Dnn`` model is
not there: this reads the same camelCase wire form into ``contract.dnnsplit.DnnSplit`` (the
rule's model, in seconds, as ``domain.dnnpairs.model_of`` builds it for the planner) and the
plan's three keys. Every error names the key, e.g. ``dnn.splitPoints[1].headMillis: missing``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fogfleet.contract.dnn import (
    FULL_OFFLOAD,
    KEY_PLANNED_ACTION,
    KEY_ROBOT_FACTOR,
    KEY_TAIL_FACTOR,
    SPEC_KEY,
)
from fogfleet.contract.dnnsplit import DnnSplit, SplitPoint, Spotlight
from fogfleet.contract.quantity import parse_quantity

__all__ = ["DnnRunSpec", "action_names"]


@dataclass(frozen=True)
class DnnRunSpec:
    """The rule's model, the plan's factors and its chosen action."""

    model: DnnSplit
    robot_factor: float  # the robot's seconds per reference-core second
    tail_factor: float  # the planned tail node's
    planned_action: str

    @property
    def planned_index(self) -> int:
        """The planned action's index (contract.dnnsplit's numbering)."""
        return action_names(self.model).index(self.planned_action)

    @classmethod
    def from_raw(cls, raw: Mapping[str, Any]) -> DnnRunSpec:
        """``raw`` is the whole module spec; ValueError names the key that is wrong."""
        dnn = raw.get(SPEC_KEY)
        if not isinstance(dnn, Mapping):
            raise ValueError(f"{SPEC_KEY}: missing (a split module's spec.dnn, as the operator "
                             "renders it)")  # fmt: skip
        model = _model(dnn)
        planned = dnn.get(KEY_PLANNED_ACTION)
        names = action_names(model)
        if planned not in names:
            raise ValueError(
                f"{SPEC_KEY}.{KEY_PLANNED_ACTION}: {planned!r} is not one of "
                + ", ".join(repr(n) for n in names)
            )
        return cls(
            model,
            _number(dnn, KEY_ROBOT_FACTOR, SPEC_KEY, positive=True),
            _number(dnn, KEY_TAIL_FACTOR, SPEC_KEY, positive=True),
            str(planned),
        )


def action_names(model: DnnSplit) -> list[str]:
    """Every action's name by index: full offload, the split points, the local model."""
    return [FULL_OFFLOAD, *(p.name for p in model.split_points), model.local_name]


def _model(dnn: Mapping[str, Any]) -> DnnSplit:
    where = SPEC_KEY
    spotlight = dnn.get("spotlight", Spotlight.TIME.value)
    if spotlight not in {s.value for s in Spotlight}:
        raise ValueError(
            f"{where}.spotlight: {spotlight!r} is not one of "
            + ", ".join(s.value for s in Spotlight)
        )
    local = dnn.get("localModel")
    if not isinstance(local, Mapping):
        raise ValueError(f"{where}.localModel: missing (name, robotMillis, accuracy)")
    points = dnn.get("splitPoints", [])
    if not isinstance(points, Sequence) or isinstance(points, str | bytes):
        raise ValueError(f"{where}.splitPoints: a list of split points")
    splits = tuple(_point(p, f"{where}.splitPoints[{k}]") for k, p in enumerate(points))
    names = [p.name for p in splits]
    local_name = _name(local, "name", f"{where}.localModel")
    if len(set(names)) != len(names) or local_name in names or FULL_OFFLOAD in names:
        raise ValueError(f"{where}.splitPoints: names must differ from each other, from the "
                         f"local model's and from {FULL_OFFLOAD!r}: {names}")  # fmt: skip
    gamma = dnn.get("maxRobotMillis")
    return DnnSplit(
        spotlight=Spotlight(spotlight),
        max_latency_s=_number(dnn, "maxLatencyMillis", where, positive=True) / 1e3,
        min_accuracy=_fraction(dnn, "minAccuracy", where, default=0.0),
        max_robot_s=None if gamma is None else _number(dnn, "maxRobotMillis", where) / 1e3,
        input_bytes=int(_number(dnn, "inputBytes", where, positive=True)),
        output_bytes=int(_number(dnn, "outputBytes", where, positive=True)),
        accuracy=_fraction(dnn, "accuracy", where),
        full_s=_number(dnn, "fullMillis", where, positive=True) / 1e3,
        split_points=splits,
        local_name=local_name,
        local_s=_number(local, "robotMillis", f"{where}.localModel", positive=True) / 1e3,
        local_accuracy=_fraction(local, "accuracy", f"{where}.localModel"),
    )


def _point(p: Any, where: str) -> SplitPoint:
    if not isinstance(p, Mapping):
        raise ValueError(f"{where}: an object (name, headMillis, tailMillis, tensorBytes)")
    return SplitPoint(
        _name(p, "name", where),
        _number(p, "headMillis", where, positive=True) / 1e3,
        _number(p, "tailMillis", where) / 1e3,
        int(_number(p, "tensorBytes", where, positive=True)),
    )


def _name(raw: Mapping[str, Any], key: str, where: str) -> str:
    value = raw.get(key)
    if not isinstance(value, str) or not value:
        raise ValueError(f"{where}.{key}: missing (a name)")
    return value


def _number(raw: Mapping[str, Any], key: str, where: str, positive: bool = False) -> float:
    """A number or a Kubernetes quantity (``"6Ki"``), at least 0 (above 0 if ``positive``)."""
    if key not in raw or raw[key] is None:
        raise ValueError(f"{where}.{key}: missing")
    value = raw[key]
    try:
        if isinstance(value, bool):
            raise ValueError
        number = float(value) if isinstance(value, int | float) else parse_quantity(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}.{key}: {value!r} is not a number") from None
    if not math.isfinite(number) or number < 0 or (positive and number == 0):
        raise ValueError(
            f"{where}.{key}: {value!r} must be {'above' if positive else 'at least'} 0"
        )
    return number


def _fraction(raw: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in raw and default is not None:
        return default
    value = _number(raw, key, where)
    if value > 1:
        raise ValueError(f"{where}.{key}: {value:g} is not a fraction 0-1")
    return value
