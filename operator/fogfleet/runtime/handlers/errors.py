"""The one place fogfleet errors become kopf's: InvalidSpec is permanent, DependencyUnavailable
is retried by kopf with the runtime's exponential backoff (``queue.backoff_delay`` of kopf's
retry count), and a handler that runs while the operator stops does nothing (``Stopping``:
the next leader reconciles every fleet)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

import kopf

from fogfleet.errors import DependencyUnavailable, InvalidSpec
from fogfleet.runtime.dispatch import Stopping
from fogfleet.runtime.queue import backoff_delay

__all__ = ["translated"]


@contextlib.asynccontextmanager
async def translated(runtime: Any, retry: int = 0) -> AsyncIterator[None]:
    try:
        yield
    except Stopping:
        return  # the operator stops: no traceback, no retry
    except InvalidSpec as exc:
        raise kopf.PermanentError(str(exc)) from exc
    except DependencyUnavailable as exc:
        delay = backoff_delay(runtime.deps.retry_seconds, retry)
        raise kopf.TemporaryError(str(exc), delay=delay) from exc
