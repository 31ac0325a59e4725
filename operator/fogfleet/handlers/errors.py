"""The one place fogfleet errors become kopf's: InvalidSpec is permanent, DependencyUnavailable
is retried after the runtime's retry delay."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

import kopf

from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = ["translated"]


@contextlib.asynccontextmanager
async def translated(runtime: Any) -> AsyncIterator[None]:
    try:
        yield
    except InvalidSpec as exc:
        raise kopf.PermanentError(str(exc)) from exc
    except DependencyUnavailable as exc:
        raise kopf.TemporaryError(str(exc), delay=runtime.deps.retry_seconds) from exc
