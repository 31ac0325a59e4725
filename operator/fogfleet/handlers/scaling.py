"""kopf timer for shared SoftwareModules with ``spec.scaling``: one scaling decision per period.

The decision (Prometheus and API calls) runs in the runtime's worker threads. ``memo.scaling``
is the :class:`~fogfleet.controllers.scaling.ScalingDeps` the composition root builds; its
``period_seconds`` is the timer's interval.
"""

from __future__ import annotations

import time
from typing import Any

import kopf

from fogfleet import GROUP, VERSION
from fogfleet.controllers.scaling import reconcile_scaling

from .errors import translated

__all__ = ["module_scaling", "register"]


async def module_scaling(body: kopf.Body, memo: Any, **_: Any) -> None:
    """Decide once; InvalidSpec of the module is permanent, an API outage is retried."""
    async with translated(memo.runtime):
        await memo.runtime.call(reconcile_scaling, dict(body), memo.scaling, time.time())


def register(registry: kopf.OperatorRegistry, interval: float) -> None:
    kopf.timer(
        GROUP,
        VERSION,
        "softwaremodules",
        interval=interval,
        field="spec.scaling",
        value=kopf.PRESENT,
        registry=registry,
    )(module_scaling)
