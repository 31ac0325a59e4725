"""kopf handlers for RobotFleet: create, update, resume and the drift timer all reconcile."""

from __future__ import annotations

from typing import Any

from .errors import translated

__all__ = ["fleet_changed", "fleet_deleted", "fleet_drift"]


async def fleet_changed(namespace: str | None, name: str, memo: Any, **_: Any) -> None:
    """Create, update and resume: one level-based reconcile."""
    async with translated(memo.runtime):
        await memo.runtime.reconcile_fleet(namespace or "default", name)


async def fleet_drift(namespace: str | None, name: str, memo: Any, **_: Any) -> None:
    """The periodic drift check: the same reconcile (a no-op when nothing changed)."""
    async with translated(memo.runtime):
        await memo.runtime.reconcile_fleet(namespace or "default", name)


async def fleet_deleted(namespace: str | None, name: str, memo: Any, **_: Any) -> None:
    """Remove the fleet's Deployments before the finalizer goes."""
    async with translated(memo.runtime):
        await memo.runtime.delete_fleet(namespace or "default", name)
