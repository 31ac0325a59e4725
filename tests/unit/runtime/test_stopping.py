"""An operator that stops (or loses its Lease) while kopf still calls its handlers: they do
nothing and say nothing, instead of a traceback per fleet ("cannot schedule new futures after
shutdown") and a retry that can never succeed."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from fogfleet.controllers.deps import Deps
from fogfleet.runtime.dispatch import Runtime, Stopping
from fogfleet.runtime.handlers.robotfleet import fleet_changed, fleet_deleted


def test_handlers_called_after_the_runtime_closed_do_nothing_quietly(
    caplog: pytest.LogCaptureFixture,
) -> None:
    calls: list[str] = []
    kube = SimpleNamespace(
        list_deployments=lambda *_: calls.append("list") or [],
        delete_deployment=lambda *_: calls.append("delete"),
    )

    async def main() -> None:
        runtime = Runtime(Deps(kube=kube))
        await runtime.close()
        memo = SimpleNamespace(runtime=runtime)
        await fleet_changed("wh", "warehouse", memo)
        await fleet_deleted("wh", "warehouse", memo)
        with pytest.raises(Stopping):
            await runtime.call(print)
        assert not runtime.queue.pending()

    asyncio.run(main())
    assert calls == []  # nothing reached the API server
    assert not [r for r in caplog.records if r.levelname in ("WARNING", "ERROR")]
