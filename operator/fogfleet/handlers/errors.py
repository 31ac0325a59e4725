"""The one place fogfleet errors become kopf's: InvalidSpec is permanent, DependencyUnavailable
is retried by kopf with the runtime's exponential backoff (``queue.backoff_delay`` of kopf's
retry count)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

import kopf

from fogfleet.controllers.queue import backoff_delay
from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = ["translated"]


@contextlib.asynccontextmanager
async def translated(runtime: Any, retry: int = 0) -> AsyncIterator[None]:
    try:
        yield
    except InvalidSpec as exc:
        raise kopf.PermanentError(str(exc)) from exc
    except DependencyUnavailable as exc:
        delay = backoff_delay(runtime.deps.retry_seconds, retry)
        raise kopf.TemporaryError(str(exc), delay=delay) from exc
