"""The module itself: rclpy subscriptions and publishers, and the cycle loop (eq. 4).

A cycle starts every ``cycleTimeMillis`` (or as soon as the previous one ends, if later; the
simulator's rule). It takes the freshest message of each input, burns the profile's work for
the CPU the module was given and publishes its outputs stamped with the input's send time.
Its cycle time is the freshest input's transfer time plus the time from the cycle's start to
the end of publishing; a cycle longer than ``cycleTimeMillis`` is missed. While the module is
inactive (Table II's activation rate, as on/off episodes like the simulator's) no cycle runs.
"""

from __future__ import annotations

import random
import signal
import threading
import time
from typing import Any

from .fallback import FirstResponse, Role, Source, Takeover, remote_topic
from .messages import Header, decode, encode
from .metrics import WorkloadMetrics
from .spec import WorkloadSpec, mean_episode_s
from .work import work_for

__all__ = ["run_module"]


class _Activity:
    """The two-state on/off process of sim.episodes, sampled as time goes by."""

    def __init__(self, activation: float, rng: random.Random) -> None:
        self.activation = activation
        self.rng = rng
        self.active = activation >= 1.0 or rng.random() < activation
        self.until = self._next(time.monotonic())

    def _next(self, now: float) -> float:
        if self.activation >= 1.0:
            return float("inf")
        on, off = mean_episode_s(self.activation)
        return now + self.rng.expovariate(1.0 / (on if self.active else off))

    def is_active(self, now: float) -> bool:
        while now >= self.until:
            self.active = not self.active
            self.until = self._next(self.until)
        return self.active


def run_module(
    spec: WorkloadSpec,
    host: str = "0.0.0.0",
    port: int = 9100,
    seed: int | None = None,
    duration: float | None = None,
) -> WorkloadMetrics:
    """Run until SIGTERM (or `duration` seconds, for tests); returns the metrics."""
    rng = random.Random(seed)
    work = work_for(spec, rng)  # forks a row's workers: before ROS starts
    import rclpy
    from rclpy.experimental.events_executor import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    metrics = WorkloadMetrics(
        spec.module, spec.robot, spec.tier, spec.hardware_type, spec.cpu_label
    )
    server = metrics.serve(host, port)
    rclpy.init()
    node = rclpy.create_node(spec.module.replace("-", "_"))
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    latest: dict[str, tuple[Header, int]] = {}
    lock = threading.Lock()

    def on_message(topic: str) -> Any:
        def callback(msg: Any) -> None:
            now = time.time_ns()
            header = decode(msg.data)
            metrics.received(topic)
            if header is None:
                return
            if spec.robot and header.robot and header.robot != spec.robot:
                metrics.foreign(topic, header.robot)
                return
            metrics.input_seen(topic, time.monotonic(), header.origin_ns)
            with lock:
                latest[topic] = (header, now)

        return callback

    for t in spec.subscribes:
        node.create_subscription(String, t.name, on_message(t.name), qos)
    # a remote instance with a standby publishes on T/remote; the standby alone publishes T
    out_name = {
        t.name: remote_topic(t.name) if spec.role is Role.REMOTE else t.name for t in spec.publishes
    }
    publishers = {
        t.name: node.create_publisher(String, out_name[t.name], qos) for t in spec.publishes
    }
    seq = 0
    last_origin = 0
    standby = spec.role is Role.STANDBY
    takeover = Takeover(
        spec.takeover_cycle_s, spec.silent_cycles, spec.step_back_cycles, started=time.monotonic()
    )
    first = FirstResponse()
    counted = 0  # takeovers already in the metric
    silent_since: float | None = None  # the remote's last output before the last takeover

    def claimed(topic: str, source: Source, origin: int) -> bool:
        """Only a standby arbitrates; the others always publish."""
        if not standby:
            return True
        with lock:
            ok = first.claim(topic, source, origin)
        if not ok:
            metrics.held_back(topic)
        return ok

    def relay(topic: str) -> Any:
        """The standby forwards the remote's answer unless it answered that input itself."""

        def callback(msg: Any) -> None:
            header = decode(msg.data)
            with lock:
                takeover.remote_output(time.monotonic())
            if header is not None and claimed(topic, Source.REMOTE, header.origin_ns):
                publishers[topic].publish(msg)
                metrics.published(topic)

        return callback

    if standby:
        for t in spec.publishes:
            node.create_subscription(String, remote_topic(t.name), relay(t.name), qos)

    def on_board(now: float) -> bool:
        """Whether this process computes the outputs now (a standby only while in charge)."""
        if not standby:
            return True
        nonlocal counted, silent_since
        with lock:
            active = takeover.should_run(now)
            metrics.fallback_active.set(1.0 if active else 0.0)
            if takeover.takeovers > counted:
                metrics.takeovers.inc(takeover.takeovers - counted)
                counted = takeover.takeovers
                last = takeover.last_remote
                silent_since = takeover.started if last is None else last
        return active

    def publish(topic: str, size: int, origin: int) -> None:
        nonlocal seq, silent_since
        if not claimed(topic, Source.STANDBY, origin):
            return
        if silent_since is not None:  # a standby's first own output after taking over
            metrics.takeover_gap.set(time.monotonic() - silent_since)
            silent_since = None
        seq += 1
        header = Header(spec.robot, spec.module, seq, time.time_ns(), origin)
        publishers[topic].publish(String(data=encode(header, size)))
        metrics.published(topic)

    def streams() -> None:
        """Outputs faster than one per cycle repeat the latest result at their own rate."""
        fast = [t for t in spec.publishes if t.rate_hz * spec.cycle_s > 1.0]
        due = {t.name: time.monotonic() for t in fast}
        while fast and not stop.is_set():
            now = time.monotonic()
            for t in fast:
                if now >= due[t.name]:
                    if on_board(now):
                        publish(t.name, t.size_bytes, last_origin or time.time_ns())
                    due[t.name] = max(due[t.name] + 1.0 / t.rate_hz, now)
            # sleep until the next output is due (no polling: the module's own CPU is work)
            stop.wait(max(0.0, min(due.values()) - time.monotonic()))

    def cycles() -> None:
        nonlocal last_origin
        activity = _Activity(spec.activation, rng)
        start = time.monotonic()
        while not stop.is_set():
            if not activity.is_active(start) or not on_board(time.monotonic()):
                start += spec.cycle_s
                stop.wait(max(0.0, start - time.monotonic()))
                continue
            with lock:
                fresh = [latest[t.name] for t in spec.subscribes if t.name in latest]
            if spec.subscribes and not fresh:  # nothing to work on yet
                start += spec.cycle_s
                stop.wait(max(0.0, start - time.monotonic()))
                continue
            # eq. 4's t_in: the transfer of the freshest input (what the cycle works on); an
            # older input's transfer was counted by the cycle it arrived for
            newest, received = max(fresh, key=lambda hr: hr[0].sent_ns, default=(None, 0))
            t_in = 0.0 if newest is None else (received - newest.sent_ns) / 1e9
            origin = min((h.sent_ns for h, _ in fresh), default=time.time_ns())
            metrics.execution.observe(work.run())
            for t in spec.publishes:
                if t.rate_hz * spec.cycle_s <= 1.0:
                    publish(t.name, t.size_bytes, origin)
            last_origin = origin
            end = time.monotonic()
            metrics.cycle_done(max(0.0, t_in) + (end - start), spec.cycle_s)
            start = max(start + spec.cycle_s, end)
            stop.wait(max(0.0, start - time.monotonic()))

    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    workers = [threading.Thread(target=f, daemon=True) for f in (cycles, streams)]
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
        work.close()
        server.shutdown()
        server.server_close()
    return metrics
