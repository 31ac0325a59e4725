"""Pieces shared by the three kinds: metadata, conditions, enums."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import Field

from .base import FogModel

__all__ = [
    "Condition",
    "ConditionStatus",
    "LabelSelector",
    "ObjectMeta",
    "Tier",
]

Name = Annotated[
    str,
    Field(min_length=1, max_length=253, pattern=r"^[a-z0-9]([-a-z0-9.]*[a-z0-9])?$"),
]


class Tier(StrEnum):
    """Where a node sits: on a robot, in the edge (LAN) or in the cloud (WAN)."""

    ROBOT = "robot"
    EDGE = "edge"
    CLOUD = "cloud"


class ObjectMeta(FogModel):
    """The part of metadata fogfleet reads. Everything else is passed through untouched."""

    model_config = {**FogModel.model_config, "extra": "ignore"}

    name: Name
    namespace: str | None = None
    labels: dict[str, str] = Field(default_factory=dict)
    annotations: dict[str, str] = Field(default_factory=dict)
    generation: int | None = None
    uid: str | None = None
    resource_version: str | None = None


class LabelSelector(FogModel):
    """A Kubernetes label selector (matchLabels only: equality is all fleets need)."""

    match_labels: dict[str, str] = Field(default_factory=dict)
    """Labels an object must carry, all of them, with these values."""

    def matches(self, labels: dict[str, str]) -> bool:
        return all(labels.get(k) == v for k, v in self.match_labels.items())


ConditionStatus = Literal["True", "False", "Unknown"]


class Condition(FogModel):
    """A status condition (Kubernetes API conventions): CamelCase reason, readable message."""

    type: str
    """The condition's type (Ready, Planned, ...)."""
    status: ConditionStatus
    """True, False or Unknown."""
    reason: str = Field(pattern=r"^[A-Za-z]([A-Za-z0-9_,:]*[A-Za-z0-9_])?$")
    """Why, in one CamelCase word."""
    message: str = ""
    """Why, for a person."""
    last_transition_time: str | None = None
    """When the status last changed (RFC 3339)."""
    observed_generation: int | None = None
    """The metadata.generation the condition describes."""


def strip_none(value: Any) -> Any:
    """Drop None values recursively (what exclude_none does, for plain dicts)."""
    if isinstance(value, dict):
        return {k: strip_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [strip_none(v) for v in value]
    return value
