"""The relay (``workload.relay``) with real processes: two ROS 2 graphs kept apart (two domain
ids, DDS on localhost), a real Zenoh router between them, and a relay process on each side, as
the site's robot and its cloud instance have (issue 47, item 4).

The bed's test (e2e ``test_multicluster``) runs the same across the emulated WAN and measures
its round trip; this one checks what crosses and what does not, on one host.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("rclpy", reason="the [ros] extra is part of `make venv`")

from tests.integration.workload.ports import fogfleet_metrics, free_port

from fogfleet.contract.env import ENV_METRICS_HOST, ENV_METRICS_PORT
from fogfleet.contract.relay import (
    ENV_RELAY_ROUTER,
    ENV_RELAY_ROUTES,
    IN,
    OUT,
    Route,
    key_of,
    routes_json,
)
from fogfleet.workload.relay import zenoh_config

pytestmark = pytest.mark.timeout(120)

SITE_DOMAIN, CLOUD_DOMAIN = 71, 72  # the two graphs: a robot's at the site, a cloud pod's
SCAN, POSE, CAMERA = "/scan", "/pose", "/camera"  # CAMERA is on no route: it must not cross


def _relay(domain: int, routes: list[Route], router: str, port: int) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "FOGFLEET_"))}
    env |= {
        "ROS_DOMAIN_ID": str(domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
        ENV_RELAY_ROUTES: routes_json(routes),
        ENV_RELAY_ROUTER: router,
        ENV_METRICS_HOST: "127.0.0.1",
        ENV_METRICS_PORT: str(port),
    }
    return subprocess.Popen(
        [sys.executable, "-m", "fogfleet.workload", "relay", "--log-interval", "0"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


@pytest.fixture
def router() -> Iterator[str]:
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(zenoh_config("router", listen=[endpoint]))
    try:
        yield endpoint
    finally:
        session.close()


class _Graph:
    """One ROS 2 graph of this test process: its own context in its own domain."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(f"relay_test_{domain}", context=self.context)
        self.qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.stop = threading.Event()
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        import rclpy

        self.stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def test_only_the_routed_topics_cross_and_each_way_once(
    router: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The robot's /scan reaches the cloud instance, its answer on /pose comes back, and /camera,
    on no route, never reaches the cloud's graph nor the router."""
    # this process's own two graphs keep DDS on localhost too
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import zenoh
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    scan_key = key_of("ns", "fleet", "r1", SCAN)
    pose_key = key_of("ns", "fleet", "r1", POSE)
    site_routes = [Route(SCAN, scan_key, OUT), Route(POSE, pose_key, IN)]
    # a shared instance would take every robot's scan: the in key of the cloud is a pattern
    cloud_routes = [Route(SCAN, key_of("ns", "fleet", "*", SCAN), IN), Route(POSE, pose_key, OUT)]
    keys: list[str] = []
    spy = zenoh.open(zenoh_config("client", connect=[router]))
    spy_sub = spy.declare_subscriber("fogfleet/**", lambda s: keys.append(str(s.key_expr)))
    ports = [free_port(), free_port()]
    relays = [
        _relay(SITE_DOMAIN, site_routes, router, ports[0]),
        _relay(CLOUD_DOMAIN, cloud_routes, router, ports[1]),
    ]
    site, in_cloud = _Graph(SITE_DOMAIN), _Graph(CLOUD_DOMAIN)
    answers: dict[str, float] = {}
    cameras_in_cloud: list[str] = []
    try:
        pose = in_cloud.node.create_publisher(String, POSE, in_cloud.qos)
        in_cloud.node.create_subscription(String, SCAN, pose.publish, in_cloud.qos)
        in_cloud.node.create_subscription(
            String, CAMERA, lambda m: cameras_in_cloud.append(m.data), in_cloud.qos
        )
        site.node.create_subscription(
            String, POSE, lambda m: answers.setdefault(m.data, time.monotonic()), site.qos
        )
        # a subscriber that asks for reliable delivery (as many ROS 2 stacks do) hears it too
        reliable: list[str] = []
        strict = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        site.node.create_subscription(String, POSE, lambda m: reliable.append(m.data), strict)
        scan = site.node.create_publisher(String, SCAN, site.qos)
        camera = site.node.create_publisher(String, CAMERA, site.qos)
        sent: dict[str, float] = {}
        deadline = time.monotonic() + 60
        i = 0
        while len(answers) < 20 and time.monotonic() < deadline:
            data = f"scan {i}"
            sent[data] = time.monotonic()
            scan.publish(String(data=data))
            camera.publish(String(data=f"camera {i}"))
            i += 1
            time.sleep(0.1)
        assert len(answers) >= 20, _outputs(relays, f"{len(answers)} of {i} scans answered")
        rtts = sorted(answers[d] - sent[d] for d in answers)
        print(f"\nrelayed round trip on one host: median {rtts[len(rtts) // 2] * 1e3:.1f} ms")
        assert set(answers) <= set(sent), "an answer to a scan never sent"
        assert not cameras_in_cloud, "a topic on no route reached the cloud's graph"
        assert set(answers) <= set(reliable), "a reliable subscriber missed what the relay told"
        assert set(keys) == {scan_key, pose_key}, keys
        # what each relay carried, on its metrics port (its probes' listener too)
        site_counts = fogfleet_metrics(ports[0])
        out = site_counts['fogfleet_relayed_messages_total{direction="out",topic="/scan"}']
        assert out >= len(answers)
        assert 'fogfleet_relayed_messages_total{direction="in",topic="/pose"}' in site_counts
        assert not any(CAMERA in k for k in site_counts)
    finally:
        site.close()
        in_cloud.close()
        for p in relays:
            p.terminate()
        for p in relays:
            p.wait(timeout=10)
        del spy_sub
        spy.close()
    assert [p.returncode for p in relays] == [0, 0], _outputs(relays, "a relay did not stop")


def _outputs(relays: list[subprocess.Popen[str]], what: str) -> str:
    out: list[Any] = [what]
    for p in relays:
        if p.poll() is not None and p.stdout is not None:
            out.append(p.stdout.read())
    return "\n".join(map(str, out))


def test_bad_routes_are_refused_with_the_field_named() -> None:
    env = dict(os.environ, **{ENV_RELAY_ROUTES: '[{"topic": "scan"}]', ENV_RELAY_ROUTER: "x"})
    done = subprocess.run(
        [sys.executable, "-m", "fogfleet.workload", "relay"],
        env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2
    assert f"{ENV_RELAY_ROUTES}[0]: needs topic, key and direction" in done.stderr
