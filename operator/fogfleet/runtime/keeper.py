"""``fogfleet hub-keeper``: the hub keeper's loop (``controllers.keeper``), run beside the OCM
hub with the hub's own credentials; it stops at SIGTERM or SIGINT."""

from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Any

from fogfleet.adapters.hub import HubClient
from fogfleet.adapters.kube import load_config
from fogfleet.controllers.keeper import keep
from fogfleet.errors import FogfleetError

__all__ = ["run_keeper"]

log = logging.getLogger("fogfleet.keeper")


def run_keeper(
    kubeconfig: str | None,
    gone_after: float,
    period: float,
    stop: threading.Event | None = None,
) -> int:
    """Keep the hub every ``period`` seconds until stopped."""
    stop = stop or threading.Event()

    def stopping(_signum: int, _frame: Any) -> None:
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, stopping)
    hub = HubClient(load_config(kubeconfig))
    log.info("Parking the works of sites gone for %.0f s, every %.0f s", gone_after, period)
    while not stop.is_set():
        try:
            keep(hub, time.time(), gone_after)
        except FogfleetError as exc:  # the next pass retries
            log.warning("Keeping the hub's works failed: %s", exc)
        stop.wait(period)
    return 0
