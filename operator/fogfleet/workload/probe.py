"""The cycle-time probe: a sidecar that measures a module nobody instrumented.

It runs beside the module in its pod (``python -m fogfleet.workload probe``), reads the same
``FOGFLEET_MODULE_SPEC`` the operator gives every container, subscribes to the module's
inputs and outputs, and serves the metrics contract for it:

- **cycle time** of each output message = the time it reaches the probe minus the stamp of
  the input it answers. ROS 2 convention carries that stamp along: a node copies its input's
  ``header.stamp`` into the output's header (a pose stamped with its scan's time), so for any
  message type with a ``std_msgs/Header`` the probe needs nothing from the module. The
  fogfleet workload's own messages carry it as the header's origin. For an event-driven node
  (a callback per input, the usual ROS 2 shape) this is eq. 4's cycle: input transfer +
  execution + output, plus the output's hop to the probe, which in the same pod is loopback.
  For a timer-driven node it also holds the wait from the input's arrival to the next timer
  tick (up to one period): the age of the data the output was computed from, which is what a
  consumer of the output sees. The probe cannot see the tick, so it reports that age;
- a cycle longer than ``cycleTimeMillis`` is **missed** (F4);
- message counters per topic, and messages stamped by another robot (isolation leaks).

Message types are resolved at run time from the ROS graph (``pkg/msg/Type`` imported from the
installed message packages), so the probe subscribes to whatever the module publishes.
"""

from __future__ import annotations

import importlib
import os
import signal
import threading
import time
from typing import Any

from .messages import decode
from .metrics import WorkloadMetrics
from .spec import WorkloadSpec

__all__ = ["CycleMeter", "message_class", "run_probe", "stamp_of"]


def stamp_of(msg: Any) -> tuple[int, str] | None:
    """(stamp in ns since the epoch, sender robot or "") of the input an output answers, or
    None when the message carries no stamp."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None:
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        return (ns, "") if ns > 0 else None
    data = getattr(msg, "data", None)
    if isinstance(data, str):
        found = decode(data)
        if found is not None:
            return (found.origin_ns or found.sent_ns), found.robot
    return None


class CycleMeter:
    """Cycle times from output stamps (pure: time and messages come in as arguments)."""

    def __init__(self, metrics: WorkloadMetrics, robot: str, cycle_s: float) -> None:
        self.metrics = metrics
        self.robot = robot
        self.cycle_s = cycle_s
        self._last: dict[str, int] = {}

    def output(self, topic: str, msg: Any, now_ns: int) -> float | None:
        """Count an output message; return its cycle time in seconds (None: not a new cycle
        or no stamp). Outputs that repeat a stamp (a stream faster than the cycle) count once."""
        self.metrics.received(topic)
        found = stamp_of(msg)
        if found is None:
            return None
        stamp, sender = found
        if self.robot and sender and sender != self.robot:
            self.metrics.foreign(topic, sender)
            return None
        if self._last.get(topic) == stamp:
            return None
        self._last[topic] = stamp
        seconds = max(0.0, (now_ns - stamp) / 1e9)
        self.metrics.cycle_done(seconds, self.cycle_s)
        return seconds

    def input(self, topic: str, msg: Any) -> None:
        self.metrics.received(topic)
        found = stamp_of(msg)
        if found and self.robot and found[1] and found[1] != self.robot:
            self.metrics.foreign(topic, found[1])


def message_class(type_name: str) -> Any:
    """``sensor_msgs/msg/LaserScan`` -> the class, from the installed message package."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def run_probe(
    spec: WorkloadSpec, host: str = "0.0.0.0", port: int = 9101, duration: float | None = None
) -> WorkloadMetrics:
    """Run until SIGTERM (or `duration` seconds, for tests); returns the metrics."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    metrics = WorkloadMetrics(spec.module, spec.robot, spec.tier)
    meter = CycleMeter(metrics, spec.robot, spec.cycle_s)
    server = metrics.serve(host, port)
    # A discovery server tells a plain client only about endpoints matching its own, so the
    # probe could never learn the types of topics it has not subscribed to yet; a super
    # client sees the whole graph (as `ros2 topic list` does).
    os.environ.setdefault("ROS_SUPER_CLIENT", "TRUE")
    rclpy.init()
    node = rclpy.create_node(f"{spec.module.replace('-', '_')}_cycle_probe")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    outputs = {t.name for t in spec.publishes}
    wanted = outputs | {t.name for t in spec.subscribes}
    subscribed: set[str] = set()
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())

    def callback(topic: str) -> Any:
        if topic in outputs:
            return lambda msg: meter.output(topic, msg, time.time_ns())
        return lambda msg: meter.input(topic, msg)

    def subscribe_new() -> None:
        """Subscribe to each wanted topic once the graph says what type it has."""
        for name, types in node.get_topic_names_and_types():
            topic = name.lstrip("/")
            for wanted_name in wanted - subscribed:
                if wanted_name.lstrip("/") == topic and types:
                    node.create_subscription(
                        message_class(types[0]), wanted_name, callback(wanted_name), qos
                    )
                    subscribed.add(wanted_name)

    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = None if duration is None else time.monotonic() + duration
    next_look = 0.0
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            if subscribed != wanted and time.monotonic() >= next_look:
                subscribe_new()
                next_look = time.monotonic() + 1.0
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        server.shutdown()
        server.server_close()
    return metrics
