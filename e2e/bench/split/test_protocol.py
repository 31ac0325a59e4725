"""The split benchmark's protocol and report, without a bed."""

from __future__ import annotations

import math

from e2e.bench.split.protocol import (
    ARMS,
    GAMMA_MS,
    Counters,
    Window,
    schedule,
    summary,
    verdict,
)
from e2e.bench.split.report import table


def _window(
    arm: str, link: str, frames: float, late: float, robot_ms: float, block: int = 0
) -> Window:
    before = Counters(100, 5, 0, 1.0, 2.0)
    after = Counters(100 + frames, 5 + late, 0, 1.0 + robot_ms * frames / 1e3, 2.0 + 0.02 * frames)
    return Window.between(before, after, block=block, arm=arm, link=link, seconds=30.0,
                          cycle_s=0.1, action="bneck")  # fmt: skip


def test_every_block_runs_every_arm_once_and_no_arm_always_first() -> None:
    runs = schedule(3)
    assert [sorted(a for b, a in runs if b == k) for k in range(3)] == [sorted(ARMS)] * 3
    assert {runs[0][1], runs[3][1], runs[6][1]} == set(ARMS)


def test_frames_never_started_count_as_over_alpha() -> None:
    w = _window("whole-edge", "slow", frames=120, late=120, robot_ms=0)
    assert w.over_alpha == 300  # 300 camera frames, none answered in time
    w = _window("whole-edge", "slow", frames=120, late=20, robot_ms=0)
    assert w.over_alpha == 200  # 180 frames were never started
    assert _window("split", "slow", frames=301, late=0, robot_ms=4.6).over_alpha == 0
    assert math.isclose(_window("split", "slow", 300, 0, 4.6).robot_ms, 4.6)


def _windows(robot_ms: float) -> list[Window]:
    out = []
    for b in range(3):
        out += [
            _window("split", "slow", 300, b, 4.6, b),
            _window("whole-edge", "slow", 100, 100, 0.0, b),
            _window("whole-robot", "slow", 300, 0, robot_ms, b),
        ]
    return out


def test_the_best_whole_placement_is_the_one_within_the_robot_budget() -> None:
    v = verdict(summary(_windows(robot_ms=8.0)))
    assert v["wholeWithinBudget"] == ["whole-edge"] and v["best"] == "whole-edge"
    assert math.isclose(v["reduction"], 1 - 1 / 300) and v["met"]
    # a whole network within the budget and never late: the split cannot be 50 % below 0
    v = verdict(summary(_windows(robot_ms=GAMMA_MS - 1)))
    assert v["best"] == "whole-robot" and v["reduction"] is None and not v["met"]


def test_the_table_gives_each_arm_and_the_verdict() -> None:
    windows = _windows(robot_ms=8.0)
    summ = summary(windows)
    text = table({
        "protocol": {"windowSeconds": 30, "cycleMillis": 100},
        "summary": summ, "verdict": verdict(summ),
    })  # fmt: skip
    assert "over alpha of 300" in text
    assert "whole-edge, 300.0 frames over alpha; split 1.0 (0 % of its frames by the local " in text
    assert "99.7% fewer" in text
    assert "met" in text and "over maxRobotMillis 6" in text
