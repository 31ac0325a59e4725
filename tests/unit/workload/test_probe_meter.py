"""CycleMeter: cycle times from output stamps, without ROS (messages are plain objects)."""

from __future__ import annotations

from types import SimpleNamespace

from fogfleet.workload.messages import Header, encode
from fogfleet.workload.metrics import WorkloadMetrics
from fogfleet.workload.probe import CycleMeter, message_class, stamp_of

S = 1_000_000_000


def stamped(ns: int) -> SimpleNamespace:
    """A message with a std_msgs/Header, as any ROS 2 sensor or pose message has."""
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=ns // S, nanosec=ns % S))
    )


def meter() -> tuple[CycleMeter, WorkloadMetrics]:
    metrics = WorkloadMetrics("localizer", "robot-1", "edge")
    return CycleMeter(metrics, "robot-1", cycle_s=0.1), metrics


def sample(metrics: WorkloadMetrics, name: str) -> float:
    """A cycle metric of the probe (no hardware type or CPU: it times another module)."""
    labels = {**metrics._ids, "hardware_type": "", "cpu": ""}
    return float(metrics.registry.get_sample_value(name, labels) or 0.0)


def test_a_header_stamp_gives_the_cycle_and_a_late_one_is_missed() -> None:
    m, metrics = meter()
    assert m.output("pose", stamped(10 * S), 10 * S + 40_000_000) == 0.04
    assert m.output("pose", stamped(11 * S), 11 * S + 150_000_000) == 0.15
    assert sample(metrics, "fogfleet_cycle_time_seconds_count") == 2
    assert sample(metrics, "fogfleet_missed_cycles_total") == 1


def test_a_stream_repeating_one_stamp_counts_one_cycle() -> None:
    m, metrics = meter()
    for k in range(5):
        m.output("pose", stamped(10 * S), 10 * S + k * 1_000_000)
    assert sample(metrics, "fogfleet_cycle_time_seconds_count") == 1


def test_workload_messages_use_their_origin_and_name_a_foreign_robot() -> None:
    m, metrics = meter()
    own = SimpleNamespace(data=encode(Header("robot-1", "localizer", 1, 12 * S, 11 * S), 64))
    assert stamp_of(own) == (11 * S, "robot-1")
    assert m.output("pose", own, 11 * S + 20_000_000) == 0.02
    other = SimpleNamespace(data=encode(Header("robot-2", "localizer", 1, 12 * S, 11 * S), 64))
    assert m.output("pose", other, 12 * S) is None
    assert (
        metrics.registry.get_sample_value(
            "fogfleet_foreign_messages_total",
            {**metrics._ids, "topic": "pose", "sender": "robot-2"},
        )
        == 1
    )


def test_messages_without_a_stamp_are_counted_but_not_timed() -> None:
    m, metrics = meter()
    assert m.output("pose", SimpleNamespace(data=b"raw"), 5 * S) is None
    assert stamp_of(stamped(0)) is None  # an unset stamp is not a time
    assert sample(metrics, "fogfleet_cycle_time_seconds_count") == 0


def test_message_types_resolve_from_the_installed_packages() -> None:
    from std_msgs.msg import String

    assert message_class("std_msgs/msg/String") is String
