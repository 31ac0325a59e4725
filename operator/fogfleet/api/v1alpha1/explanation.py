"""ExplanationRequest (namespaced): ``kubectl fogfleet why`` asked of the operator.

The operator holds each fleet's last plan in memory: the snapshot it planned from, the
problem and the placement it deployed. Rebuilding those from the API's objects is what makes
``why`` slow on a large fleet (at 1000 robots the plugin lists 1 400 ComputeNodes and Nodes
and builds a problem of 8 000 instances), so the plugin asks instead: it creates a request,
the operator answers in its status from the plan it holds, and the plugin reads the answer and
deletes the request. The pattern is Velero's ``DownloadRequest`` and
``ServerStatusRequest``: a namespaced object, so who may ask about a namespace's fleets is
plain RBAC (``create`` on ``explanationrequests`` in that namespace).

The explanation is the document ``kubectl fogfleet why -o json`` prints
(``snapshot.live.why_doc``), whichever side computed it.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from fogfleet.api.kinds import (
    EXPLANATIONREQUESTS,
    MAX_EXPLAINED,
    ExplanationFailure,
    ExplanationPhase,
)

from .base import FogModel
from .common import Name, ObjectMeta

__all__ = [
    "ExplanationFailure",
    "ExplanationPhase",
    "ExplanationRequest",
    "ExplanationRequestSpec",
    "ExplanationRequestStatus",
]


class ExplanationRequestSpec(FogModel):
    """What to explain: a module of a fleet in the request's namespace (of one robot)."""

    fleet: Name
    """The RobotFleet, in the request's namespace."""
    module: Name
    """The SoftwareModule whose instances are explained."""
    robot: Name | None = None
    """Only this robot's instance (default: every robot's, up to ``limit``)."""
    limit: int = Field(default=50, ge=1, le=MAX_EXPLAINED)
    """Instances explained at most; the rest are counted in ``omittedInstances``."""


class ExplanationRequestStatus(FogModel):
    """The operator's answer, written once."""

    phase: ExplanationPhase | None = None
    """Answered, or Failed with the reason in ``message``."""
    reason: ExplanationFailure | None = None
    """Why the request failed, in one word (with ``message``)."""
    message: str | None = None
    """Why the request failed, in words."""
    answered_time: str | None = None
    """When the operator answered (RFC 3339); the operator deletes a request some minutes
    after answering it, if the asker has not."""
    plan_generation: int | None = None
    """The RobotFleet's ``metadata.generation`` the explained plan was made for."""
    explanation: dict[str, Any] | None = None
    """The document ``kubectl fogfleet why -o json`` prints: per instance, its node and CPU,
    its predicted misses, and for every other node why not there (a rule the node breaks, or
    each objective's change were it moved)."""
    shared_nodes: str | None = None
    """Who else holds how many cores on the fleet's nodes, when other fleets or pods do (the
    room the fleet was planned into)."""


class ExplanationRequest(FogModel):
    """A question to the operator: why does each instance of a module run where it does?"""

    PLURAL: ClassVar[str] = EXPLANATIONREQUESTS
    """The resource name in API paths (``/apis/fogfleet.io/v1alpha1/.../explanationrequests``)."""

    api_version: Literal["fogfleet.io/v1alpha1"] = "fogfleet.io/v1alpha1"
    kind: Literal["ExplanationRequest"] = "ExplanationRequest"
    metadata: ObjectMeta
    spec: ExplanationRequestSpec
    status: ExplanationRequestStatus | None = None
