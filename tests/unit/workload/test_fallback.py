"""The standby's two decisions (workload/fallback.py), without ROS."""

from __future__ import annotations

import pytest

from fogfleet.workload.fallback import FirstResponse, Source, Takeover, remote_topic
from fogfleet.workload.spec import ENV_ROLE, ENV_SPEC, WorkloadSpec

CYCLE = 0.1


def _heard_every_cycle(t: Takeover, start: float, end: float) -> None:
    now = start
    while now < end:
        t.remote_output(now)
        t.should_run(now)
        now = round(now + CYCLE, 6)


def test_takeover_only_after_the_silence_window_and_once() -> None:
    t = Takeover(CYCLE, silent_cycles=3, step_back_cycles=10, started=0.0)
    _heard_every_cycle(t, 0.0, 1.0)  # last output at 0.9
    assert not t.active and t.takeovers == 0
    assert not t.should_run(0.9 + 0.29)  # within three cycles: still the remote's
    assert t.should_run(0.9 + 0.31)
    assert t.should_run(5.0) and t.takeovers == 1  # stays in charge, counted once


def test_a_standby_that_never_hears_the_remote_takes_over_after_its_start_window() -> None:
    t = Takeover(CYCLE, silent_cycles=3, started=10.0)
    assert not t.should_run(10.2)
    assert t.should_run(10.31)


def test_steps_back_only_after_the_remote_delivered_for_the_whole_window() -> None:
    t = Takeover(CYCLE, silent_cycles=3, step_back_cycles=10, started=0.0)
    assert t.should_run(1.0)
    _heard_every_cycle(t, 2.0, 2.95)  # back for 0.9 s: not yet
    assert t.active
    t.remote_output(3.0)
    assert not t.should_run(3.0)  # 1.0 s = ten cycles of the remote delivering


def test_a_flickering_link_does_not_hand_back() -> None:
    t = Takeover(CYCLE, silent_cycles=3, step_back_cycles=10, started=0.0)
    assert t.should_run(1.0)
    for burst in (2.0, 3.0, 4.0):  # half a second of outputs, then half a second of silence
        _heard_every_cycle(t, burst, burst + 0.5)
        assert t.should_run(burst + 0.95)
    assert t.takeovers == 1


def test_first_response_wins_per_input() -> None:
    fr = FirstResponse()
    assert fr.claim("objects", Source.STANDBY, 100)
    assert not fr.claim("objects", Source.REMOTE, 100)  # the same input, answered already
    assert not fr.claim("objects", Source.REMOTE, 90)  # an older input, late over the link
    assert fr.claim("objects", Source.STANDBY, 100)  # a stream repeating its latest answer
    assert fr.claim("objects", Source.REMOTE, 110)  # a newer input: whoever comes first
    assert not fr.claim("objects", Source.STANDBY, 110)
    assert fr.claim("pose", Source.REMOTE, 50)  # topics are independent
    assert fr.dropped == 3


def test_remote_topic_names() -> None:
    assert remote_topic("objects") == "objects/remote"
    assert remote_topic("/perception/objects/") == "/perception/objects/remote"


def _env(**extra: str) -> dict[str, str]:
    spec = '{"cycleTimeMillis": 100, "fallback": {"silentCycles": 4, "stepBackCycles": 20}}'
    return {ENV_SPEC: spec, **extra}


def test_the_spec_carries_the_role_and_the_windows() -> None:
    spec = WorkloadSpec.from_env(_env(**{ENV_ROLE: "standby"}))
    assert (spec.role.value, spec.silent_cycles, spec.step_back_cycles) == ("standby", 4, 20)
    assert WorkloadSpec.from_env({ENV_SPEC: '{"cycleTimeMillis": 100}'}).role.value == "primary"


@pytest.mark.parametrize(
    ("env", "says"),
    [
        (_env(**{ENV_ROLE: "backup"}), "FOGFLEET_ROLE='backup'"),
        ({ENV_SPEC: '{"cycleTimeMillis": 100, "fallback": {"silentCycles": 0}}'}, "silentCycles"),
    ],
)
def test_bad_fallback_settings_are_named(env: dict[str, str], says: str) -> None:
    with pytest.raises(ValueError, match=says):
        WorkloadSpec.from_env(env)


def test_input_gaps_and_out_of_order_answers_are_counted() -> None:
    from prometheus_client import generate_latest

    from fogfleet.workload.metrics import WorkloadMetrics

    m = WorkloadMetrics("safety", "robot-1", "robot")
    for t, origin in ((0.0, 100), (0.08, 200), (0.16, 300), (2.66, 250), (2.74, 400), (2.82, 0)):
        m.input_seen("objects", t, origin)
    text = generate_latest(m.registry).decode()

    def value(series: str) -> float:
        line = next(ln for ln in text.splitlines() if ln.startswith(series))
        return float(line.rsplit(" ", 1)[1])

    def gaps_up_to(le: str) -> float:
        return value(f'fogfleet_input_gap_seconds_bucket{{le="{le}",module="safety"')

    assert gaps_up_to("0.1") == 4  # four 80 ms gaps
    assert gaps_up_to("2.0") == 4 and gaps_up_to("5.0") == 5  # and the 2.5 s one
    # 250 answers an older input than 300: out of turn; 0 (not an answer) never is
    assert value("fogfleet_out_of_order_messages_total{") == 1
