"""A frame of the head and the tail's replies, on a clock the test moves (no ROS, no ONNX)."""

from __future__ import annotations

from headbed import (
    ALPHA,
    CYCLE,
    HEAD_S,
    LOCAL_S,
    ONE_WAY,
    TAIL_S,
    Clock,
    FakeMailbox,
    Link,
    Parts,
    TailParts,
    run_frames,
    setup_head,
)
from runspecs import SPEC

from fogfleet.workload.dnn.decide import HYSTERESIS_FRAMES
from fogfleet.workload.dnn.head import EXPLORE_FRAMES, By, Head
from fogfleet.workload.dnn.runspec import DnnRunSpec
from fogfleet.workload.dnn.tail import Tail
from fogfleet.workload.dnn.wire import Kind, Packet


def test_the_tail_answers_the_planned_split_within_alpha() -> None:
    head, link, clock = setup_head()
    results = run_frames(head, link, clock, 10)
    assert {(r.action, r.by) for r in results} == {("bneck", By.TAIL)}
    expected = HEAD_S + 2 * ONE_WAY + TAIL_S
    assert all(abs(r.real_s - expected) < 1e-9 and not r.late for r in results)
    kinds = [p.kind for p in link.sent[:2]]
    assert kinds == [Kind.PROBE, Kind.TENSOR]  # the probe leaves first
    estimate = head.decider.link.link()
    assert estimate is not None and abs(estimate.latency - ONE_WAY) < 1e-9
    assert results[-1].proposed == "bneck"


def test_a_silent_tail_makes_the_local_model_answer_after_alpha_then_at_once() -> None:
    head, link, clock = setup_head()
    run_frames(head, link, clock, 5)
    link.up = False
    results = run_frames(head, link, clock, 5)
    first, rest = results[0], results[1:]
    assert (first.action, first.by) == ("bneck", By.TIMEOUT) and first.answer == b"local"
    # answered within alpha + the local model's time, and counted as late
    assert abs(first.real_s - (ALPHA + LOCAL_S)) < 1e-9 and first.late
    assert all(r.by is By.LOCAL and r.action == "tiny" for r in rest)
    assert all(r.real_s < ALPHA for r in rest)
    # probes go on while the link is down: they will see it come back
    assert sum(p.kind is Kind.PROBE for p in link.sent[-4:]) == 4


def test_the_split_returns_after_the_hysteresis_when_the_tail_is_back() -> None:
    head, link, clock = setup_head()
    run_frames(head, link, clock, 5)
    link.up = False
    run_frames(head, link, clock, 5)
    link.up = True
    results = run_frames(head, link, clock, HYSTERESIS_FRAMES + 3)
    actions = [r.action for r in results]
    # the first frame still decides on the cut; its probe's echo shows the link is back, and
    # the split returns once the rule has proposed it HYSTERESIS_FRAMES frames in a row
    assert actions[:HYSTERESIS_FRAMES] == ["tiny"] * HYSTERESIS_FRAMES
    assert actions[HYSTERESIS_FRAMES:] == ["bneck"] * 3
    assert results[-1].by is By.TAIL


def test_a_late_answer_still_measures_the_link() -> None:
    head, link, clock = setup_head()
    run_frames(head, link, clock, 3)
    before = head.decider.link.moving_s.value
    sent = clock.t + HEAD_S  # when this frame's tensor leaves
    link.up = False
    r = head.frame()
    assert r.by is By.TIMEOUT
    # its answer comes 80 ms late: after alpha (the frame was answered), before the next
    clock.t = sent + 0.080
    head.receive(Packet(Kind.ANSWER, 2, r.frame, int(sent * 1e9), 1200, b"tail"))
    after = head.decider.link.moving_s.value
    assert before is not None and after is not None and after > before


def test_the_tail_echoes_probes_and_answers_tensors_with_its_compute_time() -> None:
    clock = Clock()
    out: list[Packet] = []
    refused: list[str] = []
    tail = Tail(TailParts(), out.append, clock, refused.append)
    tail.receive(Packet(Kind.PROBE, 2, 7, 123))
    tail.receive(Packet(Kind.TENSOR, 2, 7, 456, payload=b"x"))
    tail.receive(Packet(Kind.TENSOR, 9, 8, 789, payload=b"x"))
    assert [(p.kind, p.frame, p.sent_ns) for p in out] == [(Kind.ECHO, 7, 123),
                                                           (Kind.ANSWER, 7, 456)]  # fmt: skip
    assert out[1].payload == b"tail" and tail.answered == 1
    assert refused and "action 9" in refused[0]


class SlowLink(Link):
    """A link of ``RATE`` bit/s whose queue drops a tensor over ``QUEUE_BYTES`` (a token
    bucket's limit): a tensor's answer comes its serialisation later; probes pass."""

    RATE, QUEUE_BYTES = 5e6, 100_000

    def __init__(self, clock: Clock) -> None:
        super().__init__(clock)
        self.slow = False
        self.size: dict[tuple[int, int], int] = {}

    def send(self, packet: Packet) -> None:
        if self.slow and packet.kind is Kind.TENSOR:
            if len(packet.payload) > self.QUEUE_BYTES:
                self.sent.append(packet)  # sent, lost in the queue
                return
            self.size[packet.frame, packet.action] = len(packet.payload)
        super().send(packet)

    def _reply(self, packet: Packet) -> None:
        super()._reply(packet)
        if packet.kind is Kind.ANSWER and self.slow:
            at, p = self.queue[-1]
            self.queue[-1] = (
                at + self.size.pop((packet.frame, packet.action), 0) * 8 / self.RATE,
                p,
            )


def test_a_link_too_slow_for_the_raw_frame_moves_the_head_to_the_bottleneck_split() -> None:
    # the cost spotlight offloads the whole network while the link is fast; then the link
    # slows to 5 Mbit/s and its queue drops the raw frame (150 kB) but passes probes and
    # bneck's 6 kB: the raw frame's answer never comes, yet its probe does
    spec = {**SPEC, "dnn": {**SPEC["dnn"], "spotlight": "cost", "plannedAction": "full offload"}}
    clock = Clock()
    link = SlowLink(clock)
    head = Head(DnnRunSpec.from_raw(spec), Parts(clock), link.send, clock,
                FakeMailbox(clock, link))  # fmt: skip
    link.head = head
    fast = run_frames(head, link, clock, 5)
    assert {(r.action, r.by) for r in fast} == {("full offload", By.TAIL)}
    link.slow = True
    slow = run_frames(head, link, clock, HYSTERESIS_FRAMES + 10)
    # one raw frame waits alpha; the time it waited bounds the bandwidth, so full offload
    # misses alpha and the head leaves it; bneck's answers then measure the 5 Mbit/s, and the
    # head never goes back to the raw frame
    timeouts = [r.frame for r in slow if r.by is By.TIMEOUT]
    assert len(timeouts) == 1, [(r.action, r.by) for r in slow]
    assert all(r.action == "bneck" and r.by is By.TAIL for r in slow[-HYSTERESIS_FRAMES:])
    # the estimate keeps the raw frame out: it could not cross within alpha at this rate
    estimate = head.decider.link.link()
    assert estimate is not None and estimate.bandwidth < 150528 * 8 / ALPHA


def test_a_tail_that_dies_mid_frame_teaches_nothing_of_the_links_speed() -> None:
    # frame 6's probe comes back but its tensor is never answered (the tail stops between
    # the two); every later probe is lost: a cut, not a slow link. When a tail is back the
    # split returns after the hysteresis, its bandwidth estimate untouched
    head, link, clock = setup_head()
    run_frames(head, link, clock, 5)
    before = head.decider.link.link()
    deliver = link.send
    link.send = lambda p: None if p.kind is Kind.TENSOR else deliver(p)  # type: ignore[method-assign]
    head.send = link.send
    (r,) = run_frames(head, link, clock, 1)
    assert r.by is By.TIMEOUT
    link.send = head.send = deliver  # type: ignore[method-assign]
    link.up = False
    run_frames(head, link, clock, 5)
    link.up = True
    results = run_frames(head, link, clock, HYSTERESIS_FRAMES + 3)
    assert [x.action for x in results[-3:]] == ["bneck"] * 3
    after = head.decider.link.link()
    assert before is not None and after is not None
    assert after.bandwidth > 0.5 * before.bandwidth


def test_a_bound_from_a_slow_spell_is_revised_by_the_trials_of_the_local_model() -> None:
    # a bound says even bneck's 10 kB cannot cross in alpha: nothing off board is left, the
    # local model answers; its trial tensors (one frame in EXPLORE_FRAMES) measure the link,
    # which is fast again, and the split returns
    head, link, clock = setup_head()
    run_frames(head, link, clock, 5)
    head.decider.link.too_slow(ALPHA, 6272 + 4000)
    stuck = run_frames(head, link, clock, 3)
    assert {r.action for r in stuck} == {"tiny"}
    results = run_frames(head, link, clock, EXPLORE_FRAMES + HYSTERESIS_FRAMES + 5)
    assert all(r.by is not By.TIMEOUT for r in results)  # a trial never holds a frame up
    assert [r.action for r in results[-3:]] == ["bneck"] * 3


def test_a_split_the_rule_left_is_re_measured_by_trials_while_another_action_runs() -> None:
    # one slow first run of bneck's head (a pod still starting, a throttled CPU) would keep its
    # estimate, and the head off bneck, for good: trials re-measure it while full offload runs
    head, link, clock = setup_head()
    head.decider.parts.ran_head(2, 0.2)  # 200 ms: bneck now predicted over alpha
    results = run_frames(head, link, clock, 4 * EXPLORE_FRAMES)
    # the first frame runs the plan's bneck (the link is not known yet), then the rule leaves it
    assert {r.action for r in results[1:EXPLORE_FRAMES]} == {"full offload"}
    trials = [p for p in link.sent if p.kind is Kind.TENSOR and p.action == 2]
    assert len(trials) >= 3  # one frame in EXPLORE_FRAMES, beside the frame's own tensor
    estimate = head.decider.parts.head[2].value
    assert estimate is not None and estimate < 0.2 * 0.8**3 + HEAD_S
    # every frame was answered by its own action's tensor, never by a trial's answer
    assert all(r.by is By.TAIL and r.action in {"full offload", "bneck"} for r in results)


class JitterLink(Link):
    """One frame's answer comes ``delay`` late (queued behind something else), then none."""

    def __init__(self, clock: Clock, late_frame: int, delay: float) -> None:
        super().__init__(clock)
        self.late_frame, self.delay = late_frame, delay

    def _reply(self, packet: Packet) -> None:
        super()._reply(packet)
        if packet.kind is Kind.ANSWER and packet.frame == self.late_frame:
            at, p = self.queue[-1]
            self.queue[-1] = (at + self.delay, p)


def test_one_answer_just_over_alpha_is_a_late_sample_not_a_bound_on_the_link() -> None:
    # frame 6's answer comes a cycle late, after frame 7's probe echoed: a jittery frame,
    # not a link too slow for bneck's tensor. Its round trip is measured; the bandwidth is
    # not capped, so bneck stays within alpha and returns after the hysteresis
    clock = Clock()
    link = JitterLink(clock, late_frame=6, delay=CYCLE)
    head = Head(DnnRunSpec.from_raw(SPEC), Parts(clock), link.send, clock,
                FakeMailbox(clock, link))  # fmt: skip
    link.head = head
    bounds: list[tuple[float, int]] = []
    head.decider.link.too_slow = lambda s, b: bounds.append((s, b))  # type: ignore[method-assign]
    results = run_frames(head, link, clock, 5 + HYSTERESIS_FRAMES + 5)
    assert [r.by for r in results].count(By.TIMEOUT) == 1
    assert bounds == []  # the late answer was measured as a sample, not taken as lost
    assert [r.action for r in results[-3:]] == ["bneck"] * 3
