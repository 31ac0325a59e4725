"""The relay between a ROS 2 graph and Zenoh: the cut edges of a plan across the WAN (issue 47,
item 4; ``contract.relay`` says what a route is).

One relay runs at the site for each robot with an instance in a cloud cluster, in that robot's
discovery network, and one beside each cloud instance, in its pod. Each is a client of its
side's Zenoh router; the site's router dials the cloud's. A relay carries exactly its routes:

* ``out``: a raw subscription (``create_subscription(..., raw=True)``): the CDR bytes DDS
  delivered, put on the route's Zenoh key as they are;
* ``in``: a Zenoh subscriber whose samples are published raw (``Publisher.publish(bytes)``).

Nothing is decoded, so the relay works for any message type the image has, and costs a copy.
It hears best effort and tells reliably, each with a short queue, so it matches every
publisher and every subscriber of its topics; across Zenoh a message held by a cut WAN arrives
late or not at all, and the module's cycle meter counts it so. It is a bridge, not an engine:
rmw_zenoh or eProsima's DDS Router replace it where a user has them (docs/multicluster.md).
"""

from __future__ import annotations

import json
import signal
import threading
import time
from collections.abc import Sequence
from typing import Any

from prometheus_client import CollectorRegistry, Counter, start_http_server

from fogfleet.contract.relay import IN, OUT, Route

from .probe import message_class

__all__ = ["Counts", "run_relay", "zenoh_config"]


class Counts:
    """Messages relayed per route: the relay's log line, and ``fogfleet_relayed_messages_total``
    (``topic``, ``direction``) on its metrics port, whose listener is also its probes'."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.sent: dict[str, int] = {}
        self.registry = CollectorRegistry()
        self.relayed = Counter(
            "fogfleet_relayed_messages", "Messages relayed between DDS and Zenoh",
            ["topic", "direction"], registry=self.registry,
        )  # fmt: skip

    def add(self, route: Route) -> None:
        with self.lock:
            self.sent[route.topic] = self.sent.get(route.topic, 0) + 1
        self.relayed.labels(route.topic, route.direction).inc()

    def snapshot(self) -> dict[str, int]:
        with self.lock:
            return dict(self.sent)


def zenoh_config(mode: str, listen: Sequence[str] = (), connect: Sequence[str] = ()) -> Any:
    """A Zenoh config in ``mode`` (router, peer, client) with the endpoints given and no
    scouting (no multicast, no gossip): a session reaches nothing but the endpoints it is
    given. The relay is a client of one router (``zenoh_config("client", connect=[router])``)."""
    import zenoh

    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    cfg.insert_json5("connect/endpoints", json.dumps(list(connect)))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "false")
    return cfg


def _bridge(node: Any, session: Any, routes: Sequence[Route], counts: Counts) -> list[Any]:
    """Declare every route's two ends; returns what must stay referenced while it runs."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    # what matches every endpoint: a best-effort subscriber hears reliable and best-effort
    # publishers alike, a reliable publisher reaches reliable and best-effort subscribers
    hear = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    tell = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    held: list[Any] = []
    for route in routes:
        kind = message_class(route.type)
        if route.direction == OUT:
            put = session.declare_publisher(route.key)

            def forward(data: bytes, route: Route = route, put: Any = put) -> None:
                put.put(data)
                counts.add(route)

            held += [put, node.create_subscription(kind, route.topic, forward, hear, raw=True)]
        elif route.direction == IN:
            publisher = node.create_publisher(kind, route.topic, tell)

            def deliver(sample: Any, route: Route = route, publisher: Any = publisher) -> None:
                publisher.publish(sample.payload.to_bytes())
                counts.add(route)

            held += [publisher, session.declare_subscriber(route.key, deliver)]
    return held


def run_relay(
    routes: Sequence[Route],
    router: str,
    name: str = "fogfleet_relay",
    duration: float | None = None,
    log_interval: float = 0.0,
    counts: Counts | None = None,
    metrics: tuple[str, int] | None = None,
) -> Counts:
    """Relay ``routes`` through the Zenoh ``router`` until SIGTERM (or ``duration`` seconds, for
    tests); returns how many messages went each way, per topic. ``metrics``: (host, port) it
    serves its counts on once every route is declared (its probes' listener)."""
    import rclpy
    import zenoh
    from rclpy.executors import SingleThreadedExecutor

    counts = counts or Counts()
    stop = threading.Event()
    config = zenoh_config("client", connect=[router])
    # wait for the router however long it takes, and find it again after it restarts: a relay
    # that started first, or outlived its router, carries on instead of crashing into a
    # restart back-off
    config.insert_json5("connect/timeout_ms", "-1")
    config.insert_json5("connect/exit_on_failure", "false")
    print(f"relay: dialling {router}", flush=True)
    session = zenoh.open(config)  # SIGTERM's default action ends a relay still waiting here
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        held = _bridge(node, session, routes, counts)
        server = None
        if metrics is not None:
            server, _ = start_http_server(metrics[1], metrics[0], registry=counts.registry)
        what = ", ".join(f"{r.topic} {r.direction} {r.key}" for r in routes)
        print(f"relay: {len(routes)} routes through {router}: {what}", flush=True)
        deadline = None if duration is None else time.monotonic() + duration
        next_log = time.monotonic() + log_interval
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
            if log_interval and time.monotonic() >= next_log:
                print(f"relay: relayed {counts.snapshot()}", flush=True)
                next_log += log_interval
        if server is not None:
            server.shutdown()
        del held
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        session.close()  # type: ignore[no-untyped-call]  # zenoh ships no annotation for it
    return counts
