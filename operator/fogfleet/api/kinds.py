"""The kinds' resource names, and the words of an ExplanationRequest's status: constants the
Kubernetes adapter and ``kubectl fogfleet`` use without loading the wire models (pydantic
models take a quarter of a second to import, and ``kubectl fogfleet why`` is a command a user
waits for). The models name these (``RobotFleet.PLURAL`` is ``ROBOTFLEETS``)."""

from __future__ import annotations

from enum import StrEnum

__all__ = [
    "COMPUTENODES",
    "EXPLANATIONREQUESTS",
    "MAX_EXPLAINED",
    "ROBOTFLEETS",
    "SOFTWAREMODULES",
    "ExplanationFailure",
    "ExplanationPhase",
]

ROBOTFLEETS = "robotfleets"
SOFTWAREMODULES = "softwaremodules"
COMPUTENODES = "computenodes"
EXPLANATIONREQUESTS = "explanationrequests"

MAX_EXPLAINED = 500  # instances one answer explains at most (the status stays well under 1 MiB)


class ExplanationPhase(StrEnum):
    """Where a request stands: answered, or refused with the reason in ``message``."""

    ANSWERED = "Answered"
    FAILED = "Failed"


class ExplanationFailure(StrEnum):
    """Why a request failed: the asker explains by itself, but for an invalid request."""

    NO_PLAN_HELD = "NoPlanHeld"  # not planned yet, placed by kube-scheduler, not watched
    FLEET_NOT_FOUND = "FleetNotFound"
    INVALID_REQUEST = "InvalidRequest"  # no such module or robot in the fleet's plan
    TOO_LARGE = "TooLarge"  # the answer would not fit in an object: the asker explains
