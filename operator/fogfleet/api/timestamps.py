"""Timestamps as the Kubernetes API writes them (RFC 3339, UTC, whole seconds), in one place."""

from __future__ import annotations

import time
from datetime import UTC, datetime

__all__ = ["parse_timestamp", "timestamp"]

_FORMAT = "%Y-%m-%dT%H:%M:%SZ"


def timestamp(seconds: float | None = None) -> str:
    """``seconds`` since the epoch (default: now) as ``2026-11-23T07:30:00Z``."""
    return datetime.fromtimestamp(time.time() if seconds is None else seconds, UTC).strftime(
        _FORMAT
    )


def parse_timestamp(text: str | None) -> float | None:
    """Seconds since the epoch, or None for a missing or malformed stamp."""
    if not text:
        return None
    try:
        return datetime.strptime(text, _FORMAT).replace(tzinfo=UTC).timestamp()
    except ValueError:
        return None
