"""kopf handlers for what fleets depend on: SoftwareModules, ComputeNodes, Nodes, Deployments;
and for the questions asked of fleets: ExplanationRequests.

Watch events only (nothing is written to the first four); the runtime filters out events that
do not change planning inputs and debounces the rest into one re-plan per fleet. A request is
answered in its status (``controllers/fleet/explain.py``), beside the reconciles.
"""

from __future__ import annotations

from typing import Any

import kopf

__all__ = [
    "compute_node_event",
    "deployment_event",
    "explanation_event",
    "module_event",
    "node_event",
]


async def module_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.module_event(body, type)


async def compute_node_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.compute_node_event(body, type)


async def node_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.node_event(body, type)


async def deployment_event(body: kopf.Body, memo: Any, **_: Any) -> None:
    memo.runtime.deployment_event(body)


async def explanation_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    await memo.runtime.explainer.event(body, type)
