"""Run a workload's ROS 2 node until it is told to stop: the one executor loop of the module
(``module.run_module``) and of a split module's head or tail (``dnn.ros.run_dnn``)."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from typing import Any

__all__ = ["spin_until_stopped"]


def spin_until_stopped(
    node: Any, stop: threading.Event, workers: Sequence[threading.Thread], duration: float | None
) -> None:
    """Start ``workers``, spin ``node`` until ``stop`` is set (or ``duration`` seconds pass, for
    tests), then stop the workers, the node and ROS 2. The caller closes what it opened."""
    import rclpy
    from rclpy.experimental.events_executor import EventsExecutor

    for w in workers:
        w.start()
    executor = EventsExecutor()
    executor.add_node(node)
    deadline = None if duration is None else time.monotonic() + duration
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
    finally:
        stop.set()
        for w in workers:
            w.join(timeout=5)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
