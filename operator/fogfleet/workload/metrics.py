"""The workload's Prometheus endpoint: the metrics contract plus message counters, and /healthz.

Served on 0.0.0.0:9100 in a pod (the pod's own address; Prometheus and the kubelet's probes
reach it there), 127.0.0.1 in tests.
"""

from __future__ import annotations

import gzip
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST

from fogfleet.contract.metrics import (
    CYCLE_TIME,
    EXECUTION_TIME,
    HISTOGRAM_BUCKETS_SECONDS,
    MISSED_CYCLES,
)

from .heartbeat import Tally

__all__ = ["GAP_BUCKETS_SECONDS", "WorkloadMetrics"]

# input gaps: a cycle or two (10-30 Hz topics), a fallback's takeover (a few cycles), a lost
# link (seconds to minutes)
GAP_BUCKETS_SECONDS = (
    0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.75, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0,
)  # fmt: skip


class WorkloadMetrics:
    def __init__(
        self, module: str, robot: str, tier: str, hardware_type: str = "", cpu: str = ""
    ) -> None:
        self.registry = CollectorRegistry()
        # a cycle's count and its miss change together, and a scrape reads both at one moment:
        # else a window between two scrapes could count a miss without its cycle (over 100 %)
        self._cycle_lock = threading.Lock()
        ids = {"module": module, "robot": robot, "tier": tier}
        # what one cycle's work took, by where and with how much CPU it ran: what the operator
        # learns a module's real profile from (issue 10; controllers/measure/observed.py)
        self.execution = Histogram(
            EXECUTION_TIME.removesuffix("_seconds"),
            "Execution time of one cycle's work (eq. 4's t_exe), by hardware type and CPU limit",
            [*ids, "hardware_type", "cpu"],
            unit="seconds",
            buckets=HISTOGRAM_BUCKETS_SECONDS,
            registry=self.registry,
        ).labels(**ids, hardware_type=hardware_type, cpu=cpu)
        # cycles and misses by the same labels: the operator fits the cycle's noise beside
        # the work to them (domain.observed.cycle_noise)
        self.cycle = Histogram(
            CYCLE_TIME.removesuffix("_seconds"),
            "Input transfer + execution + output of one cycle (eq. 4)",
            [*ids, "hardware_type", "cpu"],
            unit="seconds",
            buckets=HISTOGRAM_BUCKETS_SECONDS,
            registry=self.registry,
        ).labels(**ids, hardware_type=hardware_type, cpu=cpu)
        self.missed = Counter(
            MISSED_CYCLES.removesuffix("_total"),
            "Cycles longer than the module's cycle time",
            [*ids, "hardware_type", "cpu"],
            registry=self.registry,
        ).labels(**ids, hardware_type=hardware_type, cpu=cpu)
        topic_labels = [*ids, "topic"]
        self._received = Counter(
            "fogfleet_messages_received", "Messages received", topic_labels,
            registry=self.registry,
        )  # fmt: skip
        self._foreign = Counter(
            "fogfleet_foreign_messages",
            "Messages received from another robot's instance (isolation leaks)",
            [*topic_labels, "sender"],
            registry=self.registry,
        )
        self._published = Counter(
            "fogfleet_messages_published", "Messages published", topic_labels,
            registry=self.registry,
        )  # fmt: skip
        # the on-board fallback (fallback.py): whether this standby computes the outputs now,
        # how often it took over, and the answers it held back because the other source's came
        # first (duplicates that never reached the robot's topic)
        self.fallback_active = Gauge(
            "fogfleet_fallback_active",
            "1 while this standby computes the module's outputs on board",
            list(ids),
            registry=self.registry,
        ).labels(**ids)
        self.takeovers = Counter(
            "fogfleet_fallback_takeovers",
            "Times this standby took over from its silent remote instance",
            list(ids),
            registry=self.registry,
        ).labels(**ids)
        self.takeover_gap = Gauge(
            "fogfleet_fallback_takeover_gap_seconds",
            "Last takeover: from the remote's last output to this standby's first own output",
            list(ids),
            registry=self.registry,
        ).labels(**ids)
        # when it took over (Unix time, its own clock): the operator sees a cut-off robot's
        # takeover only once the link is back, and reports when it happened from this
        self.last_takeover = Gauge(
            "fogfleet_fallback_last_takeover_timestamp_seconds",
            "Last takeover: when this standby took over (Unix time)",
            list(ids),
            registry=self.registry,
        ).labels(**ids)
        self._held_back = Counter(
            "fogfleet_fallback_held_back",
            "Answers not published because the input was answered already",
            topic_labels,
            registry=self.registry,
        )
        # what a consumer sees of each input: the gaps between its messages (a robot that went
        # blind: how long, how often) and answers to an input older than one already received
        # (two sources answering out of turn: what the fallback's first-response rule prevents)
        self._gaps = Histogram(
            "fogfleet_input_gap",
            "Time between consecutive messages of an input topic",
            topic_labels,
            unit="seconds",
            buckets=GAP_BUCKETS_SECONDS,
            registry=self.registry,
        )
        self._out_of_order = Counter(
            "fogfleet_out_of_order_messages",
            "Messages answering an older input than one already received on the topic",
            topic_labels,
            registry=self.registry,
        )
        self._last_seen: dict[str, tuple[float, int]] = {}  # topic -> (monotonic s, origin)
        self._ids = ids
        self.healthy = True
        self.tally = Tally()  # the same counts for the module's log line (heartbeat)

    def received(self, topic: str) -> None:
        self._received.labels(**self._ids, topic=topic).inc()
        self.tally.received()

    def input_seen(self, topic: str, now_s: float, origin_ns: int) -> None:
        """A message of input ``topic`` arrived at ``now_s`` (monotonic), answering the input
        sent at ``origin_ns`` (0: not an answer)."""
        prev = self._last_seen.get(topic)
        newest = origin_ns
        if prev is not None:
            self._gaps.labels(**self._ids, topic=topic).observe(max(0.0, now_s - prev[0]))
            if 0 < origin_ns < prev[1]:
                self._out_of_order.labels(**self._ids, topic=topic).inc()
            newest = max(prev[1], origin_ns)
        self._last_seen[topic] = (now_s, newest)

    def foreign(self, topic: str, sender: str) -> None:
        self._foreign.labels(**self._ids, topic=topic, sender=sender).inc()

    def published(self, topic: str) -> None:
        self._published.labels(**self._ids, topic=topic).inc()
        self.tally.published()

    def held_back(self, topic: str) -> None:
        self._held_back.labels(**self._ids, topic=topic).inc()

    def cycle_done(self, seconds: float, limit: float) -> None:
        with self._cycle_lock:
            self.cycle.observe(seconds)
            if seconds > limit:
                self.missed.inc()
        self.tally.cycle(seconds > limit)

    def exposition(self) -> bytes:
        """The registry in Prometheus' text format, cycles and misses read at one moment."""
        with self._cycle_lock:
            body: bytes = generate_latest(self.registry)
        return body

    def serve(self, host: str, port: int) -> ThreadingHTTPServer:
        metrics = self

        class Handler(BaseHTTPRequestHandler):
            # keep-alive, gzip, and the headers and body in one write (unbuffered, the body
            # waited for the ACK of the headers: Nagle's rule against the scraper's delayed
            # ACK): a scrape is then one round trip over the robot's link, so the fastest
            # scrape measures the link (controllers/measure/links.py), and it costs the link less
            protocol_version = "HTTP/1.1"
            wbufsize = 1 << 16  # handle_one_request flushes it once the answer is complete
            disable_nagle_algorithm = True

            def do_GET(self) -> None:
                if self.path.startswith("/metrics"):
                    body, ctype = metrics.exposition(), CONTENT_TYPE_LATEST
                elif self.path == "/healthz" and metrics.healthy:
                    body, ctype = b"ok\n", "text/plain"
                else:
                    self.send_response(404 if self.path != "/healthz" else 503)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                self.send_response(200)
                self.send_header("Content-Type", ctype)
                if "gzip" in self.headers.get("Accept-Encoding", ""):
                    body = gzip.compress(body, compresslevel=1)
                    self.send_header("Content-Encoding", "gzip")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *_: Any) -> None:
                return

        server = ThreadingHTTPServer((host, port), Handler)
        threading.Thread(target=server.serve_forever, name="metrics", daemon=True).start()
        return server
