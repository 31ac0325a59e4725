"""The head's choice per frame: the rule over its estimates, with hysteresis."""

from __future__ import annotations

from runspecs import SPEC, spec

from fogfleet.workload.dnn.decide import HYSTERESIS_FRAMES, Decider, Hysteresis
from fogfleet.workload.dnn.runspec import DnnRunSpec


def test_the_hysteresis_switches_after_n_proposals_in_a_row_only() -> None:
    h = Hysteresis(current=2, frames=3)
    assert [h.step(0), h.step(0)] == [2, 2]
    assert h.step(2) == 2  # the streak is broken
    assert [h.step(0), h.step(0), h.step(0)] == [2, 2, 0]
    assert h.step(1, at_once=True) == 1


def test_any_other_proposal_counts_towards_the_streak() -> None:
    h = Hysteresis(current=2, frames=2)
    assert h.step(0) == 2
    assert h.step(1) == 1  # the latest proposal wins


def _decider(**change: object) -> Decider:
    return Decider(DnnRunSpec.from_raw(spec(**change) if change else SPEC))


def test_before_the_link_is_measured_the_plans_action_runs() -> None:
    d = _decider()
    got = d.decide()
    assert got.action.name == "bneck" and got.proposed is None


def test_a_cut_switches_to_the_local_model_at_once() -> None:
    d = _decider()
    d.cut = True
    got = d.decide()
    assert got.action.name == "tiny"
    assert got.proposed is not None and "cut" in got.proposed.reason


def test_after_a_cut_the_split_returns_only_after_the_hysteresis() -> None:
    d = _decider()
    d.cut = True
    d.decide()
    d.cut = False
    d.link.echo(0.004)
    d.link.answer(0.005, 0.001, 10_000)  # a fast link: the rule proposes an off-board action
    names = [d.decide().action.name for _ in range(HYSTERESIS_FRAMES)]
    assert names[:-1] == ["tiny"] * (HYSTERESIS_FRAMES - 1)
    assert names[-1] != "tiny"


def test_a_slow_link_leaves_the_bottleneck_split_as_the_rule_says() -> None:
    """10 Mbit/s, 2 ms: the raw frame (150 kB: 120 ms) and b6 (401 kB) miss alpha = 50 ms;
    the local model is below minAccuracy; bneck (6 kB: 5 ms) is left."""
    d = _decider(plannedAction="full offload")
    d.link.echo(0.004)
    for _ in range(3):
        d.link.answer(0.004 + 10_272 * 8 / 10e6, 0.0012, 10_272)
    # full offload now misses alpha: the head leaves it at once (no hysteresis to wait out)
    names = [d.decide().action.name for _ in range(HYSTERESIS_FRAMES)]
    assert names == ["bneck"] * HYSTERESIS_FRAMES
    got = d.decide()
    assert got.proposed is not None and got.proposed.action.name == "bneck"
    assert 0.0 < got.predicted_s < 0.05


def test_the_robots_budget_bounds_its_cpu_not_the_waits_for_a_cpu() -> None:
    # bneck's head took 4 ms on the wall clock but 2 ms of CPU (a throttled pod waited the
    # rest): the frame's time counts the 4 ms, maxRobotMillis 3 the 2 ms, so bneck stays
    d = _decider(maxRobotMillis=3)
    d.link.echo(0.002)
    d.link.answer(0.004, 0.0012, 10_000)
    d.parts.ran_head(2, 0.004, cpu_s=0.002)
    bneck = next(a for a in d.candidates() if a.name == "bneck")
    assert bneck.robot_s == 0.002 and bneck.time_s > 0.004
    assert d.decide().proposed is not None and d.decide().proposed.action.name == "bneck"
    # without its CPU time the wall time is what the budget sees, and bneck is out
    d.parts.robot_cpu.clear()
    d.parts.ran_head(2, 0.004)
    assert next(a for a in d.candidates() if a.name == "bneck").robot_s == 0.004
    assert d.decide().proposed.action.name != "bneck"  # type: ignore[union-attr]
