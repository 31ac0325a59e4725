"""The network run whole (``--whole``), the baselines of ``make bench-split``: on the edge
every frame's raw input crosses and waits for the answer with no local model; on the robot
the whole network runs there. On the head's test bed (no ROS, no ONNX)."""

from __future__ import annotations

from functools import partial

from headbed import ALPHA, ONE_WAY, TAIL_S, WHOLE_S, run_frames, setup_head

from fogfleet.contract.dnn import FULL_OFFLOAD
from fogfleet.workload.dnn.head import By
from fogfleet.workload.dnn.whole import UNANSWERED_AFTER, WHOLE_ON_ROBOT, Whole, WholeHead
from fogfleet.workload.dnn.wire import Kind


def test_on_the_edge_every_frame_sends_its_raw_input_and_waits_for_the_whole_network() -> None:
    head, link, clock = setup_head(partial(WholeHead, Whole.EDGE))
    results = run_frames(head, link, clock, 5)
    assert {(r.action, r.by, r.answer) for r in results} == {(FULL_OFFLOAD, By.TAIL, b"tail")}
    sent = [p for p in link.sent if p.kind is Kind.TENSOR]
    assert [(p.action, len(p.payload)) for p in sent] == [(0, 150528)] * 5  # no probes, no head
    # the head's test bed takes HEAD_S to hand over the raw frame; the robot computes nothing
    assert all(r.robot_s == 0.0 and not r.late for r in results)
    assert all(abs(r.real_s - (0.002 + 2 * ONE_WAY + TAIL_S)) < 1e-9 for r in results)


def test_on_the_edge_a_frame_whose_answer_never_comes_has_no_local_model_to_answer_it() -> None:
    head, link, clock = setup_head(partial(WholeHead, Whole.EDGE))
    link.up = False
    results = run_frames(head, link, clock, 3)
    assert {(r.by, r.answer) for r in results} == {(By.UNANSWERED, b"")}
    # it waited ten alphas, not one: a module on the edge waits for its answer
    assert all(abs(r.real_s - UNANSWERED_AFTER * ALPHA) < 1e-9 and r.late for r in results)


def test_on_the_robot_the_whole_network_runs_there_and_nothing_crosses() -> None:
    head, link, clock = setup_head(partial(WholeHead, Whole.ROBOT))
    results = run_frames(head, link, clock, 4)
    assert {(r.action, r.by, r.answer) for r in results} == {(WHOLE_ON_ROBOT, By.ROBOT, b"whole")}
    assert link.sent == []
    assert all(abs(r.robot_s - WHOLE_S) < 1e-9 and abs(r.real_s - WHOLE_S) < 1e-9 for r in results)


def test_the_rules_head_counts_its_robot_compute() -> None:
    head, link, clock = setup_head()
    results = run_frames(head, link, clock, 3)
    assert all(abs(r.robot_s - 0.002) < 1e-9 for r in results)  # bneck's head, HEAD_S
