"""kopf handlers for what fleets depend on: SoftwareModules, ComputeNodes, Nodes, Deployments.

Watch events only (nothing is written to these objects); the runtime filters out events that
do not change planning inputs and debounces the rest into one re-plan per fleet.
"""

from __future__ import annotations

from typing import Any

import kopf

__all__ = ["compute_node_event", "deployment_event", "module_event", "node_event"]


async def module_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.module_event(body, type)


async def compute_node_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.compute_node_event(body, type)


async def node_event(body: kopf.Body, type: str, memo: Any, **_: Any) -> None:
    memo.runtime.node_event(body, type)


async def deployment_event(body: kopf.Body, memo: Any, **_: Any) -> None:
    memo.runtime.deployment_event(body)
