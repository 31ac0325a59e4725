"""Operator lifecycle: kopf settings on startup, login from our kubeconfig, clean shutdown."""

from __future__ import annotations

from typing import Any

import kopf

__all__ = ["cleanup", "login", "startup"]


async def startup(settings: kopf.OperatorSettings, memo: Any, **_: Any) -> None:
    """Apply fogfleet's kopf settings (storage in annotations, our finalizer, posting)."""
    from fogfleet.operator_main import configure_kopf

    configure_kopf(settings, memo.settings)
    memo.runtime.start_periodic(
        memo.settings.drift_interval_seconds, getattr(memo, "scaling", None)
    )


def login(memo: Any, **_: Any) -> kopf.ConnectionInfo:
    """kopf talks to the API server with the same credentials as our client."""
    return kopf.ConnectionInfo(**memo.runtime.deps.kube.connection_info())


async def cleanup(memo: Any, **_: Any) -> None:
    await memo.runtime.close()
