"""A split module's metrics and its log line, beside the workload's contract metrics.

They live in ``WorkloadMetrics``' registry and are served by its endpoint (``/metrics``,
``/healthz``): a frame is also the module's cycle (``fogfleet_cycle_time_seconds``, a miss
when longer than ``cycleTimeMillis``), so the operator's drift re-plan reads a split module
as any other (issue 48: "the predicted and real time per frame, which feed the drift
re-plan"; DNNSPLIT.md 3.2). The head's own:

=============================================  =========  =====================================
metric                                         type       meaning
=============================================  =========  =====================================
``fogfleet_dnn_action{module,action}``         gauge      1 for the action run now, 0 others
``fogfleet_dnn_frames_total{module,action,by}`` counter   frames by action and who answered
``fogfleet_dnn_late_frames_total{module}``     counter    frames answered after alpha
``fogfleet_dnn_timeouts_total{module}``        counter    frames the local model answered after
                                                          the tail's answer did not come
``fogfleet_dnn_robot_seconds_total{module}``   counter    the robot's CPU time for the frames
                                                          (heads, the local model)
``fogfleet_dnn_predicted_seconds{module}``     histogram  the action's Time(a) when chosen
``fogfleet_dnn_frame_seconds{module}``         histogram  the frame's real time
``fogfleet_dnn_link_latency_seconds{module}``  gauge      the estimated one-way latency
``fogfleet_dnn_link_bandwidth_bits_per_second`` gauge     the estimated bandwidth
=============================================  =========  =====================================
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence

from prometheus_client import Counter, Gauge, Histogram

from fogfleet.contract.metrics import HISTOGRAM_BUCKETS_SECONDS

from ..metrics import WorkloadMetrics
from .estimate import LinkEstimate
from .head import By, FrameResult

__all__ = ["DnnMetrics", "DnnTally", "dnn_line"]


class DnnTally:
    """The counts the log line reads (by action, late, timeouts), since the start."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.frames: dict[str, int] = {}
        self.late = self.timeouts = 0

    def add(self, result: FrameResult) -> None:
        with self._lock:
            self.frames[result.action] = self.frames.get(result.action, 0) + 1
            self.late += result.late
            self.timeouts += result.by is By.TIMEOUT

    def snapshot(self) -> tuple[dict[str, int], int, int]:
        with self._lock:
            return dict(self.frames), self.late, self.timeouts


class DnnMetrics:
    def __init__(self, base: WorkloadMetrics, module: str, actions: Sequence[str]) -> None:
        self.base, reg, ids = base, base.registry, {"module": module}
        self.actions = list(actions)
        self._action = Gauge(
            "fogfleet_dnn_action", "1 for the action the head runs now", ["module", "action"],
            registry=reg,
        )  # fmt: skip
        for a in self.actions:
            self._action.labels(module=module, action=a).set(0)
        self._frames = Counter(
            "fogfleet_dnn_frames", "Frames by the action run and who answered",
            ["module", "action", "by"], registry=reg,
        )  # fmt: skip
        self._late = Counter(
            "fogfleet_dnn_late_frames", "Frames answered after maxLatencyMillis (alpha)",
            ["module"], registry=reg,
        ).labels(**ids)  # fmt: skip
        self._timeouts = Counter(
            "fogfleet_dnn_timeouts",
            "Frames the local model answered because the tail's answer did not come in alpha",
            ["module"], registry=reg,
        ).labels(**ids)  # fmt: skip
        self._robot = Counter(
            "fogfleet_dnn_robot_seconds", "The robot's CPU time for the frames (heads, the "
            "local model; the whole network when run whole on it)", ["module"], registry=reg,
        ).labels(**ids)  # fmt: skip
        self._predicted = Histogram(
            "fogfleet_dnn_predicted", "The chosen action's predicted Time(a)", ["module"],
            unit="seconds", buckets=HISTOGRAM_BUCKETS_SECONDS, registry=reg,
        ).labels(**ids)  # fmt: skip
        self._real = Histogram(
            "fogfleet_dnn_frame", "A frame's real time, from its capture to its answer",
            ["module"], unit="seconds", buckets=HISTOGRAM_BUCKETS_SECONDS, registry=reg,
        ).labels(**ids)  # fmt: skip
        self._latency = Gauge(
            "fogfleet_dnn_link_latency_seconds", "The head's estimate of the one-way latency",
            ["module"], registry=reg,
        ).labels(**ids)  # fmt: skip
        self._bandwidth = Gauge(
            "fogfleet_dnn_link_bandwidth_bits_per_second", "The head's estimate of the bandwidth",
            ["module"], registry=reg,
        ).labels(**ids)  # fmt: skip
        self.module = module
        self.current = ""
        self.reason = ""  # the rule's last word (contract.dnnsplit.Choice.reason)
        self.tally = DnnTally()

    def frame(self, result: FrameResult, cycle_s: float) -> None:
        """One frame's counts; the contract's cycle metrics with it."""
        if result.action != self.current:
            if self.current:
                self._action.labels(module=self.module, action=self.current).set(0)
            self._action.labels(module=self.module, action=result.action).set(1)
            self.current = result.action
        self._frames.labels(module=self.module, action=result.action, by=result.by.value).inc()
        if result.late:
            self._late.inc()
        if result.by is By.TIMEOUT:
            self._timeouts.inc()
        self._robot.inc(result.robot_s)
        if math.isfinite(result.predicted_s):
            self._predicted.observe(result.predicted_s)
        self._real.observe(result.real_s)
        self.base.execution.observe(result.real_s)
        self.base.cycle_done(result.real_s, cycle_s)
        self.tally.add(result)
        self.reason = result.reason or self.reason

    def link(self, estimate: LinkEstimate | None) -> None:
        if estimate is not None:
            self._latency.set(estimate.latency)
            self._bandwidth.set(min(estimate.bandwidth, 1e15))


def dnn_line(
    who: str,
    tally: DnnTally,
    before: tuple[dict[str, int], int, int],
    seconds: float,
    current: str,
    link: LinkEstimate | None,
    reason: str = "",
) -> str:
    """``robot-1/detector: bneck now; 100 frames (bneck 100), 0 late, 0 by the local model
    after a timeout in the last 10 s; link 0.21 ms one way, 850 Mbit/s; the rule: ...``."""
    frames, late, timeouts = tally.snapshot()
    then, late0, timeouts0 = before
    d = {a: n - then.get(a, 0) for a, n in frames.items() if n - then.get(a, 0)}
    by = ", ".join(f"{a} {n}" for a, n in sorted(d.items()))
    net = "link unknown"
    if link is not None:
        mbit = "unbounded" if math.isinf(link.bandwidth) else f"{link.bandwidth / 1e6:.3g} Mbit/s"
        net = f"link {link.latency * 1e3:.3g} ms one way, {mbit}"
    return (
        f"fogfleet-workload: {who}: {current or 'no action yet'} now; {sum(d.values())} frames"
        f" ({by or 'none'}), {late - late0} late, {timeouts - timeouts0} by the local model "
        f"after a timeout in the last {seconds:g} s; {net}"
        + (f"; the rule: {reason}" if reason else "")
    )
