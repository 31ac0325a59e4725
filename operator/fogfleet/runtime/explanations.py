"""ExplanationRequests, answered beside the reconciles: each new request is answered on a
thread of its own (``asyncio.to_thread``: not on the reconcile workers, so a fleet being
planned does not hold the answer back), and an answered request is deleted
``REQUEST_TTL_SECONDS`` after its answer when the asker has not deleted it (after a restart,
the watch's first listing finds the ones already due)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Mapping
from typing import Any

from fogfleet.adapters.ports import KubePort
from fogfleet.api.timestamps import parse_timestamp
from fogfleet.controllers.fleet.explain import REQUEST_TTL_SECONDS, answer
from fogfleet.controllers.state import FleetStore
from fogfleet.errors import FogfleetError

__all__ = ["Explainer"]

log = logging.getLogger(__name__)


class Explainer:
    """Answers each ExplanationRequest once, and expires what askers leave behind."""

    def __init__(self, kube: KubePort, store: FleetStore) -> None:
        self.kube, self.store = kube, store
        self._expiring: set[tuple[str, str]] = set()

    async def event(self, body: Mapping[str, Any], event_type: str | None) -> None:
        meta = body.get("metadata") or {}
        key = (str(meta.get("namespace") or "default"), str(meta.get("name") or ""))
        if event_type == "DELETED":
            self._expiring.discard(key)
            return
        status = body.get("status") or {}
        if not status.get("phase"):
            await asyncio.to_thread(self._answer, key, dict(body))
        elif key not in self._expiring:
            self._expiring.add(key)
            answered = parse_timestamp(status.get("answeredTime")) or time.time()
            delay = max(answered + REQUEST_TTL_SECONDS - time.time(), 0.0)
            asyncio.get_running_loop().call_later(delay, self._expire_soon, key)

    def _answer(self, key: tuple[str, str], body: dict[str, Any]) -> None:
        started = time.monotonic()
        try:
            status = answer(self.kube, self.store, body, time.time())
            self.kube.patch_explanation_status(*key, status)
        except FogfleetError as exc:  # the API did not answer: the asker falls back
            log.warning("ExplanationRequest %s/%s not answered: %s", *key, exc)
            return
        log.info(
            "ExplanationRequest %s/%s %s in %.0f ms",
            *key,
            str(status["phase"]).lower(),
            (time.monotonic() - started) * 1e3,
        )

    def _expire_soon(self, key: tuple[str, str]) -> None:
        if key in self._expiring:
            asyncio.get_running_loop().run_in_executor(None, self._expire, key)

    def _expire(self, key: tuple[str, str]) -> None:
        try:
            self.kube.delete_explanation_request(*key)
        except FogfleetError as exc:
            log.warning("ExplanationRequest %s/%s not deleted: %s", *key, exc)
