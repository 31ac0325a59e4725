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

from fogfleet.contract.env import LOG_INTERVAL_SECONDS

from .fallback import FirstResponse, Role, Source, Takeover, remote_topic
from .heartbeat import run_heartbeat
from .messages import Header, decode, encode
from .metrics import WorkloadMetrics
from .spec import WorkloadSpec, mean_episode_s
from .spin import spin_until_stopped
from .work import Work, work_for

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


class _Module:
    """One running module: its subscriptions and publishers, the standby's arbitration (a
    standby publishes only while in charge, and never an input's answer twice) and the two
    loops, ``cycles`` and ``streams``, that run on their own threads until ``stop`` is set."""

    def __init__(
        self,
        spec: WorkloadSpec,
        node: Any,
        metrics: WorkloadMetrics,
        work: Work,
        rng: random.Random,
    ) -> None:
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        self.spec, self.metrics, self.work, self.rng = spec, metrics, work, rng
        self.string = String
        self.latest: dict[str, tuple[Header, int]] = {}
        self.lock = threading.Lock()
        self.stop = threading.Event()
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
        for t in spec.subscribes:
            node.create_subscription(String, t.name, self._on_message(t.name), qos)
        # a remote instance with a standby publishes on T/remote; the standby alone publishes T
        out_name = {
            t.name: remote_topic(t.name) if spec.role is Role.REMOTE else t.name
            for t in spec.publishes
        }
        self.publishers = {
            t.name: node.create_publisher(String, out_name[t.name], qos) for t in spec.publishes
        }
        self.seq = 0
        self.last_origin = 0
        self.standby = spec.role is Role.STANDBY
        self.takeover = Takeover(
            spec.takeover_cycle_s,
            spec.silent_cycles,
            spec.step_back_cycles,
            started=time.monotonic(),
        )
        self.first = FirstResponse()
        self.counted = 0  # takeovers already in the metric
        # the remote's last output before the last takeover
        self.silent_since: float | None = None
        if self.standby:
            for t in spec.publishes:
                node.create_subscription(String, remote_topic(t.name), self._relay(t.name), qos)

    def _on_message(self, topic: str) -> Any:
        spec, metrics = self.spec, self.metrics

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
            with self.lock:
                self.latest[topic] = (header, now)

        return callback

    def _claimed(self, topic: str, source: Source, origin: int) -> bool:
        """Only a standby arbitrates; the others always publish."""
        if not self.standby:
            return True
        with self.lock:
            ok = self.first.claim(topic, source, origin)
        if not ok:
            self.metrics.held_back(topic)
        return ok

    def _relay(self, topic: str) -> Any:
        """The standby forwards the remote's answer unless it answered that input itself."""

        def callback(msg: Any) -> None:
            header = decode(msg.data)
            with self.lock:
                self.takeover.remote_output(time.monotonic())
            if header is not None and self._claimed(topic, Source.REMOTE, header.origin_ns):
                self.publishers[topic].publish(msg)
                self.metrics.published(topic)

        return callback

    def _on_board(self, now: float) -> bool:
        """Whether this process computes the outputs now (a standby only while in charge)."""
        if not self.standby:
            return True
        takeover, metrics = self.takeover, self.metrics
        with self.lock:
            active = takeover.should_run(now)
            metrics.fallback_active.set(1.0 if active else 0.0)
            if takeover.takeovers > self.counted:
                metrics.takeovers.inc(takeover.takeovers - self.counted)
                metrics.last_takeover.set(time.time())
                self.counted = takeover.takeovers
                last = takeover.last_remote
                self.silent_since = takeover.started if last is None else last
        return active

    def _publish(self, topic: str, size: int, origin: int) -> None:
        if not self._claimed(topic, Source.STANDBY, origin):
            return
        if self.silent_since is not None:  # a standby's first own output after taking over
            self.metrics.takeover_gap.set(time.monotonic() - self.silent_since)
            self.silent_since = None
        self.seq += 1
        spec = self.spec
        header = Header(spec.robot, spec.module, self.seq, time.time_ns(), origin)
        self.publishers[topic].publish(self.string(data=encode(header, size)))
        self.metrics.published(topic)

    def streams(self) -> None:
        """Outputs faster than one per cycle repeat the latest result at their own rate."""
        spec, stop = self.spec, self.stop
        fast = [t for t in spec.publishes if t.rate_hz * spec.cycle_s > 1.0]
        due = {t.name: time.monotonic() for t in fast}
        while fast and not stop.is_set():
            now = time.monotonic()
            for t in fast:
                if now >= due[t.name]:
                    if self._on_board(now):
                        self._publish(t.name, t.size_bytes, self.last_origin or time.time_ns())
                    due[t.name] = max(due[t.name] + 1.0 / t.rate_hz, now)
            # sleep until the next output is due (no polling: the module's own CPU is work)
            stop.wait(max(0.0, min(due.values()) - time.monotonic()))

    def _fresh_inputs(self) -> list[tuple[Header, int]] | None:
        """The latest message of each input (None: an input-driven module has none yet)."""
        spec = self.spec
        with self.lock:
            fresh = [self.latest[t.name] for t in spec.subscribes if t.name in self.latest]
        return None if spec.subscribes and not fresh else fresh

    def _cycle(self, start: float, fresh: list[tuple[Header, int]]) -> float:
        """One cycle started at ``start`` on ``fresh``: work, publish, count; its end."""
        spec = self.spec
        # eq. 4's t_in: the transfer of the freshest input (what the cycle works on); an
        # older input's transfer was counted by the cycle it arrived for
        newest, received = max(fresh, key=lambda hr: hr[0].sent_ns, default=(None, 0))
        t_in = 0.0 if newest is None else (received - newest.sent_ns) / 1e9
        origin = min((h.sent_ns for h, _ in fresh), default=time.time_ns())
        self.metrics.execution.observe(self.work.run())
        for t in spec.publishes:
            if t.rate_hz * spec.cycle_s <= 1.0:
                self._publish(t.name, t.size_bytes, origin)
        self.last_origin = origin
        end = time.monotonic()
        self.metrics.cycle_done(max(0.0, t_in) + (end - start), spec.cycle_s)
        return end

    def cycles(self) -> None:
        """A cycle every ``cycleTimeMillis`` while active, on board and with inputs."""
        spec, stop = self.spec, self.stop
        activity = _Activity(spec.activation, self.rng)
        start = time.monotonic()
        while not stop.is_set():
            fresh = None
            if activity.is_active(start) and self._on_board(time.monotonic()):
                fresh = self._fresh_inputs()
            if fresh is None:  # idle, not in charge or nothing to work on yet: skip a cycle
                start += spec.cycle_s
            else:
                start = max(start + spec.cycle_s, self._cycle(start, fresh))
            stop.wait(max(0.0, start - time.monotonic()))


def run_module(
    spec: WorkloadSpec,
    host: str = "0.0.0.0",
    port: int = 9100,
    seed: int | None = None,
    duration: float | None = None,
    log_interval: float = LOG_INTERVAL_SECONDS,
) -> WorkloadMetrics:
    """Run until SIGTERM (or `duration` seconds, for tests), logging a line of its cycles,
    misses and messages every ``log_interval`` seconds (``heartbeat``); returns the metrics."""
    rng = random.Random(seed)
    work = work_for(spec, rng)  # forks a row's workers: before ROS starts
    import rclpy

    metrics = WorkloadMetrics(
        spec.module, spec.robot, spec.tier, spec.hardware_type, spec.cpu_label
    )
    server = metrics.serve(host, port)
    rclpy.init()
    node = rclpy.create_node(spec.module.replace("-", "_"))
    module = _Module(spec, node, metrics, work, rng)
    stop = module.stop
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    who = f"{spec.robot or 'shared'}/{spec.module}"
    workers = [threading.Thread(target=f, daemon=True) for f in (module.cycles, module.streams)]
    workers.append(
        threading.Thread(
            target=run_heartbeat, args=(metrics.tally, who, log_interval, stop), daemon=True
        )
    )
    try:
        spin_until_stopped(node, stop, workers, duration)
    finally:
        work.close()
        server.shutdown()
        server.server_close()
    return metrics
