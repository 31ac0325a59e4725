"""Operator lifecycle: kopf settings on startup, login from our kubeconfig, clean shutdown."""

from __future__ import annotations

import logging
from typing import Any

import kopf

from fogfleet import GROUP
from fogfleet.settings import Settings

__all__ = ["cleanup", "configure_kopf", "login", "startup", "watches_by_name"]


async def startup(settings: kopf.OperatorSettings, memo: Any, **_: Any) -> None:
    """Apply fogfleet's kopf settings (storage in annotations, our finalizer, posting)."""
    configure_kopf(settings, memo.settings)
    memo.runtime.start_periodic(
        memo.settings.drift_interval_seconds,
        getattr(memo, "scaling", None),
        getattr(memo, "links", None),
        getattr(memo, "observed", None),
    )


def login(memo: Any, **_: Any) -> kopf.ConnectionInfo:
    """kopf talks to the API server with the same credentials as our client."""
    return kopf.ConnectionInfo(**memo.runtime.deps.kube.connection_info())


async def cleanup(memo: Any, **_: Any) -> None:
    await memo.runtime.close()


def configure_kopf(kopf_settings: kopf.OperatorSettings, settings: Settings) -> None:
    """State in annotations under fogfleet.io, our finalizer, quiet event posting."""
    p = kopf_settings.persistence
    p.progress_storage = kopf.AnnotationsProgressStorage(prefix=GROUP)
    p.diffbase_storage = kopf.AnnotationsDiffBaseStorage(
        prefix=GROUP, key="last-handled-configuration"
    )
    p.finalizer = f"{GROUP}/finalizer"  # none is added: no handler of ours requires one
    kopf_settings.posting.level = logging.WARNING  # our own Events say what happened
    kopf_settings.posting.reporting_component = "fogfleet"
    kopf_settings.watching.server_timeout = 300
    kopf_settings.watching.client_timeout = 330
    kopf_settings.watching.connect_timeout = 10
    kopf_settings.networking.request_timeout = 60
    kopf_settings.peering.standalone = settings.standalone
    kopf_settings.peering.name = settings.peering_name
    kopf_settings.scanning.disabled = watches_by_name(settings.namespaces)


def watches_by_name(namespaces: list[str]) -> bool:
    """Whether kopf watches the served namespaces by name instead of discovering them: when
    every one is a name, not a pattern. kopf's namespace discovery lists the namespaces, then
    starts a watch whose own first listing it ignores, so a namespace created between the two
    is never served (docs/limits.md); a watch in a namespace that does not exist yet simply
    waits for it. Discovery also follows CRDs created after the start: fogfleet's are
    installed before it (crds/, the chart's templates)."""
    return bool(namespaces) and not any(set(ns) & set("*?[]!") for ns in namespaces)
