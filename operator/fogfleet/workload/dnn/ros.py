"""``python -m fogfleet.workload dnn``: a split module's head or tail as a ROS 2 node.

The two pods exchange ``std_msgs/UInt8MultiArray`` messages (``wire``) on the module's two
topics (``contract.dnn``), reliable and shallow: a frame's tensor either arrives or its frame
is answered by the local model. The head publishes each answer on the module's first output
topic as every workload module does (``std_msgs/String``, ``messages.Header`` with the frame's
capture time as its origin, then ``action=...;by=...;`` and padding to its ``sizeBytes``), so
a downstream module or the probe sidecar reads it unchanged.
"""

from __future__ import annotations

import array
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from fogfleet.contract.dnn import ROLE_HEAD, answer_topic, tensor_topic

from ..messages import Header, encode
from ..metrics import WorkloadMetrics
from ..spec import WorkloadSpec
from ..spin import spin_until_stopped
from .dnnmetrics import DnnMetrics, dnn_line
from .head import FrameResult, Head
from .runspec import DnnRunSpec, action_names
from .sessions import RobotNets, TailNets, models_folder  # models_folder: re-exported
from .tail import Tail
from .whole import Whole, WholeHead
from .wire import Packet, decode
from .wire import encode as encode_packet

__all__ = ["models_folder", "run_dnn"]

QOS_DEPTH = 4  # a few frames in flight at most: an older tensor is of no use


def run_dnn(
    spec: WorkloadSpec,
    role: str,
    folder: Path,
    host: str,
    port: int,
    log_interval: float,
    duration: float | None = None,
    link_mbit: float | None = None,
    whole: Whole | None = None,
) -> None:
    """Run the head or the tail until SIGTERM (or ``duration`` seconds). ``link_mbit``
    (experiments, the head only): each tensor is held back as long as an uplink of that many
    Mbit/s would take to carry it, so a test on one host sees a slow link's choice. ``whole``
    (experiments, the head only): the network run whole there, the rule not consulted
    (``whole.WholeHead``)."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String, UInt8MultiArray

    assert spec.dnn is not None
    run: DnnRunSpec = spec.dnn
    names = [p.name for p in run.model.split_points]
    base = WorkloadMetrics(spec.module, spec.robot, spec.tier, spec.hardware_type, spec.cpu_label)
    stop = threading.Event()
    qos = QoSProfile(depth=QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
    # the networks load before ROS starts: a tail that answers at all answers at full speed
    is_head = role == ROLE_HEAD
    robot = RobotNets(folder, names, whole=whole is Whole.ROBOT) if is_head else None
    tail_nets = None if is_head else TailNets(folder, names)
    rclpy.init()
    if threading.current_thread() is threading.main_thread():  # after rclpy's own handlers
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    node = rclpy.create_node(f"{spec.module.replace('-', '_')}_dnn_{role}")
    out, into = (
        (tensor_topic(spec.module), answer_topic(spec.module))
        if is_head
        else (answer_topic(spec.module), tensor_topic(spec.module))
    )
    publisher = node.create_publisher(UInt8MultiArray, out, qos)

    def send(packet: Packet) -> None:
        if link_mbit and packet.payload and is_head:
            time.sleep(len(packet.payload) * 8 / (link_mbit * 1e6))
        publisher.publish(UInt8MultiArray(data=array.array("B", encode_packet(packet))))

    who = f"{spec.robot or 'shared'}/{spec.module} ({role})"
    workers: list[threading.Thread] = []
    if robot is not None:
        head = (
            Head(run, robot, send, time.monotonic, cpu_clock=time.thread_time)
            if whole is None
            else WholeHead(whole, run, robot, send, time.monotonic, cpu_clock=time.thread_time)
        )
        receiver: Any = head.receive
        dnn = DnnMetrics(base, spec.module, action_names(run.model))
        answers = node.create_publisher(String, spec.publishes[0].name, qos)
        loop = _HeadLoop(spec, head, dnn, answers, String, stop)
        workers += [
            threading.Thread(target=loop.frames, name="frames", daemon=True),
            threading.Thread(target=loop.lines, args=(who, log_interval), daemon=True),
        ]
    else:
        assert tail_nets is not None
        tail = Tail(tail_nets, send, time.monotonic, lambda why: print(f"{who}: refused {why}"))
        receiver = tail.receive

    def on_message(msg: Any) -> None:
        try:
            packet = decode(msg.data.tobytes())
        except ValueError as exc:
            print(f"fogfleet-workload: {who}: dropped a message on {into}: {exc}", flush=True)
            return
        base.received(into)
        receiver(packet)

    node.create_subscription(UInt8MultiArray, into, on_message, qos)
    server = base.serve(host, port)
    print(f"fogfleet-workload: {who}: {len(names)} split points from {folder}, plan "
          f"{run.planned_action!r}; {out} out, {into} in"
          + (f"; run whole on the {whole.value} (--whole)" if whole and is_head else ""),
          flush=True)  # fmt: skip
    try:
        spin_until_stopped(node, stop, workers, duration)
    finally:
        server.shutdown()
        server.server_close()


class _HeadLoop:
    """A frame every cycle on its own thread, its answer published and counted; a log line
    every ``log_interval`` (as ``heartbeat``, with the split's own counts)."""

    def __init__(
        self, spec: WorkloadSpec, head: Head, dnn: DnnMetrics, answers: Any, string: Any,
        stop: threading.Event,
    ) -> None:  # fmt: skip
        self.spec, self.head, self.dnn, self.answers = spec, head, dnn, answers
        self.string, self.stop = string, stop

    def _publish(self, result: FrameResult, origin_ns: int) -> None:
        spec = self.spec
        topic = spec.publishes[0]
        header = Header(spec.robot, spec.module, result.frame, time.time_ns(), origin_ns)
        text = encode(header, 0) + f"action={result.action};by={result.by.value};"
        self.answers.publish(self.string(data=text + "." * max(0, topic.size_bytes - len(text))))
        self.dnn.base.published(topic.name)

    def frames(self) -> None:
        cycle = self.spec.cycle_s
        start = time.monotonic()
        while not self.stop.is_set():
            origin = time.time_ns()
            try:
                result = self.head.frame()
            except Exception as exc:  # a frame that fails is logged, the next one runs
                print(f"fogfleet-workload: frame failed: {exc!r}", file=sys.stderr, flush=True)
            else:
                self._publish(result, origin)
                self.dnn.frame(result, cycle)
                with self.head.lock:
                    self.dnn.link(self.head.decider.link.link())
            start = max(start + cycle, time.monotonic() - cycle)
            self.stop.wait(max(0.0, start - time.monotonic()))

    def lines(self, who: str, seconds: float) -> None:
        if seconds <= 0:
            return
        before = self.dnn.tally.snapshot()
        while not self.stop.wait(seconds):
            with self.head.lock:
                link = None if self.head.decider.cut else self.head.decider.link.link()
                times = ", ".join(
                    f"{a.name} {a.time_s * 1e3:.3g}" for a in self.head.decider.candidates()
                )
            line = dnn_line(
                who, self.dnn.tally, before, seconds, self.dnn.current, link, self.dnn.reason
            )
            print(f"{line}; predicted ms: {times}", flush=True)
            before = self.dnn.tally.snapshot()
