"""What crosses between a robot site and a cloud cluster: the relay's routes (issue 47, item 4;
docs/multicluster.md "What crosses the WAN").

The operator renders them (``render.relays``) into the two ends of every cut edge of the plan:
the relay of the robot at the site and the relay sidecar of the cloud instance. The relay
(``workload.relay``) reads them from its environment. Stdlib only: both sides import it.

A route is one ROS 2 topic in one direction:

* ``out``: the relay subscribes to ``topic`` in its DDS graph and puts every message, as the
  serialized bytes DDS carries, on the Zenoh key ``key``;
* ``in``: the relay subscribes to the Zenoh key expression ``key`` and publishes every sample
  on ``topic`` in its DDS graph, as the same bytes.

A relay has at most one route per topic, so a message it publishes is never taken back: nothing
it relays in is relayed out again.

Keys name where a message comes from: ``fogfleet/<namespace>/<fleet>/<robot>/<topic>``, with
``_shared`` for the robot of a shared instance (a DNS label never starts with ``_``). A shared
instance in the cloud takes its inputs from every robot (``*`` in place of the robot), as at
the site it hears every robot's discovery server.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

__all__ = [
    "ENV_RELAY_ROUTER",
    "ENV_RELAY_ROUTES",
    "IN",
    "KEY_PREFIX",
    "OUT",
    "RELAY_METRICS_PORT",
    "SHARED",
    "STRING",
    "Route",
    "key_of",
    "remote_topic",
    "routes_from_json",
    "routes_json",
]

ENV_RELAY_ROUTES = "FOGFLEET_RELAY_ROUTES"  # the routes as JSON (routes_json)
ENV_RELAY_ROUTER = "FOGFLEET_RELAY_ROUTER"  # the Zenoh router the relay is a client of
# the relay's metrics and probes (a cloud instance's sidecar shares the module's pod: not 9100)
RELAY_METRICS_PORT = 9103
KEY_PREFIX = "fogfleet"
SHARED = "_shared"  # the robot segment of a shared instance's keys
ANY_ROBOT = "*"
OUT, IN = "out", "in"
REMOTE_SUFFIX = "remote"
STRING = "std_msgs/msg/String"  # what the fogfleet workload publishes on every topic


@dataclass(frozen=True, order=True)
class Route:
    """One topic, one direction, between the relay's DDS graph and Zenoh."""

    topic: str  # the ROS 2 name in the relay's DDS graph
    key: str  # the Zenoh key (out) or key expression (in)
    direction: str  # OUT or IN
    type: str = STRING  # the ROS 2 message type, package/msg/Name

    def __post_init__(self) -> None:
        if self.direction not in (OUT, IN):
            raise ValueError(f"route {self.topic}: direction {self.direction!r} is not in or out")
        if not self.topic.startswith("/"):
            raise ValueError(f"route {self.topic}: a topic is an absolute ROS 2 name")
        if not self.key.startswith(f"{KEY_PREFIX}/") or "//" in self.key:
            raise ValueError(f"route {self.topic}: key {self.key!r} is not under {KEY_PREFIX}/")
        if self.direction == OUT and "*" in self.key:
            raise ValueError(f"route {self.topic}: an out key names one place, not {self.key!r}")
        if self.type.count("/") != 2:
            raise ValueError(f"route {self.topic}: type {self.type!r} is not package/msg/Name")


def remote_topic(name: str) -> str:
    """Where a remote instance publishes output ``name`` when its robot has an on-board standby
    (``workload.fallback``): a ROS 2 name under ``name``, which the standby relays to ``name``."""
    return f"{name.rstrip('/')}/{REMOTE_SUFFIX}"


def key_of(namespace: str, fleet: str, robot: str, topic: str) -> str:
    """The Zenoh key of ``topic`` of ``robot`` (SHARED, or ANY_ROBOT in a key expression)."""
    return "/".join((KEY_PREFIX, namespace, fleet, robot or SHARED, topic.strip("/")))


def routes_json(routes: list[Route]) -> str:
    """The routes as the relay's environment carries them (sorted: a stable spec hash)."""
    rows = [
        {"topic": r.topic, "key": r.key, "direction": r.direction, "type": r.type}
        for r in sorted(routes)
    ]
    return json.dumps(rows, separators=(",", ":"))


def routes_from_json(text: str) -> list[Route]:
    """The routes of ``routes_json``; ValueError naming the route and what is wrong with it."""
    try:
        rows = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{ENV_RELAY_ROUTES}: not JSON ({exc})") from None
    if not isinstance(rows, list):
        raise ValueError(f"{ENV_RELAY_ROUTES}: a list of routes, not {type(rows).__name__}")
    routes: list[Route] = []
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or not {"topic", "key", "direction"} <= row.keys():
            raise ValueError(f"{ENV_RELAY_ROUTES}[{i}]: needs topic, key and direction")
        topic, key, direction = str(row["topic"]), str(row["key"]), str(row["direction"])
        routes.append(Route(topic, key, direction, str(row.get("type", STRING))))
    topics = [r.topic for r in routes]
    twice = sorted({t for t in topics if topics.count(t) > 1})
    if twice:
        raise ValueError(f"{ENV_RELAY_ROUTES}: {', '.join(twice)} routed twice (one way each)")
    return routes
