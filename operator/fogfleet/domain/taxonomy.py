"""The robotics taxonomy (multi-robot-edge-cloud-scheduling III-A, Fig. 2).

Hard real-time or safety-critical modules run on their own robot ("carrot orange"); modules
without safety relevance that need not run continuously are the first to offload ("green");
everything in between is placed by the scheduler from requirements and cluster state ("blue").
"""

from __future__ import annotations

from enum import StrEnum

from fogfleet.api.v1alpha1.softwaremodule import (
    ExecutionPattern,
    SafetyClass,
    SoftwareModuleSpec,
    Taxonomy,
    default_priority,
    must_run_on_board,
)

__all__ = [
    "Offloadability",
    "classify",
    "may_degrade",
    "module_priority",
    "must_stay_onboard",
]


class Offloadability(StrEnum):
    NEVER = "never"  # orange: on its own robot only
    CANDIDATE = "candidate"  # blue: decided by requirements and cluster state
    PREFERRED = "preferred"  # green: offload first


must_stay_onboard = must_run_on_board
"""III-B: hard real-time and safety-critical modules must run on the robot (the API's rule)."""


def classify(tax: Taxonomy) -> Offloadability:
    if must_stay_onboard(tax):
        return Offloadability.NEVER
    if (
        tax.safety is SafetyClass.IRRELEVANT
        and tax.execution_pattern is not ExecutionPattern.CONTINUOUS
    ):
        return Offloadability.PREFERRED
    return Offloadability.CANDIDATE


def may_degrade(tax: Taxonomy) -> bool:
    """Whether a plan short of CPU may give this module less than its deadline needs: never a
    hard real-time or safety-critical one (a miss there is a failure, III-A)."""
    return not must_stay_onboard(tax)


def module_priority(spec: SoftwareModuleSpec) -> int:
    """``spec.priority``, else the taxonomy's default (``default_priority``)."""
    return spec.priority if spec.priority is not None else default_priority(spec.taxonomy)
