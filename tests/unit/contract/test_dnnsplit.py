"""RoboEC2's Spotlight Criteria Algorithm (``domain.dnnsplit``) on the network the bed would
run (DNNSPLIT.md 3.3: a MobileNet-like CNN with a bottleneck, measured on one core here): the
worked cases of the seed in shape, and the table of the design notes."""

from __future__ import annotations

import dataclasses
import math

import pytest

from fogfleet.contract.dnnsplit import DnnSplit, SplitPoint, Spotlight, actions, choose
from fogfleet.domain.network import Link

MS = 1e-3
PI = 25.0  # a Pi 4 core is ~25 times slower than the reference core
EDGE = 1.0

NET = DnnSplit(
    spotlight=Spotlight.TIME,
    max_latency_s=100 * MS,
    min_accuracy=0.80,
    max_robot_s=None,
    input_bytes=602_112,  # 224 x 224 x 3 fp32
    output_bytes=4_000,
    accuracy=0.92,
    full_s=3.8 * MS,
    split_points=(
        SplitPoint("b0", 0.2 * MS, 3.5 * MS, 1_605_632),
        SplitPoint("b4", 1.4 * MS, 1.9 * MS, 802_816),
        SplitPoint("b6", 2.0 * MS, 1.2 * MS, 401_408),
        SplitPoint("bneck", 2.0 * MS, 1.2 * MS, 6_272),
        SplitPoint("b9", 3.6 * MS, 0.1 * MS, 200_704),
    ),
    local_name="tiny",
    local_s=0.4 * MS,
    local_accuracy=0.61,
)


def link(mbit: float, rtt_ms: float) -> Link:
    return Link(latency=rtt_ms / 2 * MS, jitter=0.0, bandwidth=mbit * 1e6)


def chosen(spotlight: Spotlight, over: Link | None) -> tuple[str, float]:
    model = dataclasses.replace(NET, spotlight=spotlight)
    choice = choose(model, actions(model, over, PI, EDGE))
    return choice.action.name, round(choice.action.time_s / MS)


@pytest.mark.parametrize(
    ("over", "spotlight", "name", "ms"),
    [
        # DNNSPLIT.md 3.3's table (fp32 transfer)
        (link(100, 8), Spotlight.TIME, "bneck", 60),
        (link(100, 8), Spotlight.COST, "full offload", 60),
        (link(100, 8), Spotlight.ACCURACY, "full offload", 60),
        (link(20, 8), Spotlight.TIME, "bneck", 63),
        (link(20, 8), Spotlight.COST, "bneck", 63),
        (link(20, 8), Spotlight.ACCURACY, "bneck", 63),
        (link(5, 30), Spotlight.TIME, "bneck", 98),
        (None, Spotlight.TIME, "tiny", 10),
        (None, Spotlight.ACCURACY, "tiny", 10),
    ],
)
def test_the_design_notes_table(
    over: Link | None, spotlight: Spotlight, name: str, ms: float
) -> None:
    assert chosen(spotlight, over) == (name, ms)


def test_time_picks_the_fastest_and_cost_the_most_offloaded_within_alpha() -> None:
    """The seed's path planning (time: the fastest action) and object detection (cost with a
    time bound: the least robot computation that meets alpha, not full offload when it times
    out)."""
    fast = link(100, 8)
    model = dataclasses.replace(NET, local_accuracy=0.9)  # the local model may compete
    every = actions(model, fast, PI, EDGE)
    by_time = choose(dataclasses.replace(model, spotlight=Spotlight.TIME), every)
    assert by_time.action.time_s == min(a.time_s for a in every)
    assert by_time.action.name == "tiny"  # 10 ms on the robot beats any crossing
    by_cost = choose(dataclasses.replace(model, spotlight=Spotlight.COST), every)
    assert by_cost.action.name == "full offload" and by_cost.action.robot_s == 0
    slow = actions(model, link(20, 8), PI, EDGE)  # full offload takes 249 ms > alpha
    by_cost = choose(dataclasses.replace(model, spotlight=Spotlight.COST), slow)
    assert by_cost.action.name == "tiny"  # the least robot computation that meets alpha
    assert 0 < by_cost.action.robot_s < min(a.robot_s for a in slow if a.name == "bneck")


def test_accuracy_takes_an_off_board_action_even_when_the_local_one_is_faster() -> None:
    """The seed's homography: accuracy -> the big model off-board, the least robot work."""
    model = dataclasses.replace(NET, spotlight=Spotlight.ACCURACY, local_accuracy=0.9)
    choice = choose(model, actions(model, link(100, 8), PI, EDGE))
    assert choice.action.offloaded and choice.action.name == "full offload"
    assert "the spotlight is accuracy" in dict((a.name, w) for a, w in choice.dropped)["tiny"]


def test_nothing_left_runs_the_local_model_and_says_why() -> None:
    cut = choose(NET, actions(NET, None, PI, EDGE))
    assert cut.action.name == "tiny" and "the link is cut" in cut.reason
    assert all(math.isinf(a.time_s) for a, _ in cut.dropped)
    crawl = choose(NET, actions(NET, link(0.5, 200), PI, EDGE))
    assert crawl.action.name == "tiny" and "nothing meets the bounds" in crawl.reason
    # below theta, it answers all the same: the seed's n+1 when nothing is left
    assert crawl.action.accuracy < NET.min_accuracy


def test_gamma_drops_heads_too_heavy_for_the_robot() -> None:
    model = dataclasses.replace(NET, max_robot_s=40 * MS)  # bneck's head: 50 ms on the Pi
    choice = choose(model, actions(model, link(100, 8), PI, EDGE))
    assert choice.action.name == "full offload"
    why = dict((a.name, w) for a, w in choice.dropped)
    assert why["bneck"].startswith("robot 50 ms > maxRobot 40 ms")


def test_the_reason_names_the_time_the_bound_and_why_the_local_model_is_out() -> None:
    choice = choose(NET, actions(NET, link(20, 8), PI, EDGE))
    assert choice.reason.startswith("bneck: 63.3 ms <= 100 ms, 6272 B crossing (time spotlight)")
    assert "the local model is out: accuracy 0.61 < minAccuracy 0.8" in choice.reason
    assert {a.name for a, _ in choice.dropped} == {a.name for a in actions(NET, None, PI, EDGE)} - {
        "bneck"
    }
