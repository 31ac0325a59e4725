"""kopf handlers for RobotFleet: create, update and resume reconcile; delete is best effort."""

from __future__ import annotations

from typing import Any

from .errors import translated

__all__ = ["fleet_changed", "fleet_deleted", "fleet_event"]


async def fleet_changed(
    namespace: str | None, name: str, memo: Any, retry: int = 0, **_: Any
) -> None:
    """Create, update and resume: one level-based reconcile."""
    async with translated(memo.runtime, retry):
        await memo.runtime.reconcile_fleet(namespace or "default", name)


async def fleet_deleted(
    namespace: str | None, name: str, memo: Any, retry: int = 0, **_: Any
) -> None:
    """Best effort (no finalizer): forget the fleet and delete its Deployments at once; the
    garbage collector does the same through their owner references when we miss it."""
    async with translated(memo.runtime, retry):
        await memo.runtime.delete_fleet(namespace or "default", name)


async def fleet_event(
    type: str, namespace: str | None, name: str, memo: Any, retry: int = 0, **_: Any
) -> None:
    """A fleet's watch event: DELETED forgets it at once (kopf calls no delete handler for an
    object without a finalizer that is already gone), so the next usage pass drops it from
    the ComputeNodes and SoftwareModules it used."""
    if type == "DELETED":
        async with translated(memo.runtime, retry):
            await memo.runtime.delete_fleet(namespace or "default", name)
