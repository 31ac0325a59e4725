"""What one reconcile of a fleet did, for the queue (requeue) and the runtime (logs, rollout)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Outcome"]


@dataclass(frozen=True)
class Outcome:
    planned: bool = False
    applied: int = 0
    pruned: int = 0
    migrations: int = 0
    ready: bool = False
    requeue_after: float | None = None
    message: str = ""
    waiting: int = 0  # modules not yet running where planned (rolling out or moving)
    unsettled: frozenset[str] = frozenset()  # their Deployments' names
    status_write_seconds: float = 0.0  # spent patching the fleet's status
