"""The split module's metrics beside the contract's, and its log line."""

from __future__ import annotations

from prometheus_client.parser import text_string_to_metric_families

from fogfleet.workload.dnn.dnnmetrics import DnnMetrics, dnn_line
from fogfleet.workload.dnn.estimate import LinkEstimate
from fogfleet.workload.dnn.head import By, FrameResult
from fogfleet.workload.metrics import WorkloadMetrics


def _result(action: str, by: By, real: float, robot: float = 0.004) -> FrameResult:
    return FrameResult(
        1, action, by, b"", 0.0, 0.01, real, action, "why", alpha_s=0.05, robot_s=robot
    )


def _samples(m: WorkloadMetrics) -> dict[str, float]:
    out: dict[str, float] = {}
    for fam in text_string_to_metric_families(m.exposition().decode()):
        for s in fam.samples:
            key = s.name + "".join(f",{k}={v}" for k, v in sorted(s.labels.items()))
            out[key] = s.value
    return out


def test_frames_are_counted_by_action_and_by_who_answered() -> None:
    base = WorkloadMetrics("detector", "robot-1", "robot")
    dnn = DnnMetrics(base, "detector", ["full offload", "bneck", "tiny"])
    dnn.frame(_result("bneck", By.TAIL, 0.01), 0.1)
    dnn.frame(_result("bneck", By.TIMEOUT, 0.06), 0.1)
    dnn.frame(_result("tiny", By.LOCAL, 0.001), 0.1)
    dnn.link(LinkEstimate(0.002, 20e6))
    s = _samples(base)
    assert s["fogfleet_dnn_action,action=tiny,module=detector"] == 1
    assert s["fogfleet_dnn_action,action=bneck,module=detector"] == 0
    assert s["fogfleet_dnn_frames_total,action=bneck,by=local after timeout,module=detector"] == 1
    assert s["fogfleet_dnn_late_frames_total,module=detector"] == 1
    assert s["fogfleet_dnn_timeouts_total,module=detector"] == 1
    assert abs(s["fogfleet_dnn_robot_seconds_total,module=detector"] - 0.012) < 1e-12
    assert s["fogfleet_dnn_frame_seconds_count,module=detector"] == 3
    assert s["fogfleet_dnn_link_bandwidth_bits_per_second,module=detector"] == 20e6
    # a frame is the module's cycle: the contract's metrics count it too
    assert s["fogfleet_cycle_time_seconds_count,cpu=,hardware_type=,module=detector,"
             "robot=robot-1,tier=robot"] == 3  # fmt: skip


def test_the_log_line_says_the_action_the_counts_and_the_link() -> None:
    base = WorkloadMetrics("detector", "robot-1", "robot")
    dnn = DnnMetrics(base, "detector", ["bneck", "tiny"])
    before = dnn.tally.snapshot()
    dnn.frame(_result("bneck", By.TAIL, 0.01), 0.1)
    dnn.frame(_result("bneck", By.TIMEOUT, 0.06), 0.1)
    line = dnn_line("robot-1/detector", dnn.tally, before, 10, "bneck",
                    LinkEstimate(0.002, 20e6), "bneck: fastest")  # fmt: skip
    assert line == (
        "fogfleet-workload: robot-1/detector: bneck now; 2 frames (bneck 2), 1 late, 1 by the "
        "local model after a timeout in the last 10 s; link 2 ms one way, 20 Mbit/s; the "
        "rule: bneck: fastest"
    )
