"""The split benchmark's protocol, fixed 2026-11-29 before its first result (issue 48: "versus
whole-module placement on the same bed and links: at the slow link setting, the split module's
frames over alpha at least 50 % fewer than the best whole-module placement's").

* **Bed.** The default bed's real nodes: bed-robot-1 (a 400m share of this machine, Wi-Fi
  100 Mbit/s, 4 ms) and bed-edge-1 (1000m). The fleet is the split e2e tests' (``dnnbed``): one
  pose estimator per robot, the image's network, one frame per 100 ms cycle, alpha = the cycle,
  spotlight time, minAccuracy 0.8, and ``maxRobotMillis`` ``GAMMA_MS``: the robot may give the
  estimator 6 ms of a reference core per frame. That is RoboEC2's premise (the robot cannot run
  the big model): the head of either split (4.6-4.7 ms) fits, the whole network (7.9 ms) does
  not. Robot-1's head is measured; its link is set per window.
* **Arms** (the module's ``template.args``; the operator re-renders its pods):
  ``split`` (fogfleet: the planner's split and the rule per frame, the local model when the
  tail's answer is late), ``whole-edge`` (the module placed off-board: every frame's input
  crosses and waits for the whole network's answer, no local model: ``--whole edge``) and
  ``whole-robot`` (the module placed on its robot: the whole network there, ``--whole
  robot``).
* **Links.** ``fast``: the bed's declared link; ``slow``: 5 Mbit/s, 15 ms (the e2e tests'
  slow setting: the raw frame alone takes 241 ms to cross).
* **Schedule.** ``RUNS`` blocks; each block runs every arm once, in an order rotated by one per
  block; each arm's run measures ``fast`` then ``slow``. A window is ``WINDOW_S`` after a
  ``WARMUP_S`` settle at its link setting (an arm's first window also waits for its new pod's
  first frames).
* **Endpoint.** Frames over alpha per window: the frames the camera gave in the window
  (``WINDOW_S`` / cycle) less those answered within alpha, so a frame never started (the head
  still busy with an earlier one) counts as over. Secondary: frames answered, the share by the
  local model, the mean frame time, and the robot's compute per frame (measured, the
  ``fogfleet_dnn_robot_seconds_total`` counter).
* **Statistics.** Per arm and link, the median over its runs. The best whole-module placement
  at a link is the whole arm with the fewest median frames over alpha among those whose
  median robot compute per frame is within ``GAMMA_MS`` (a placement over the module's robot
  budget is not one the module allows); the target holds when the split's median at ``slow``
  is at most half of it. The whole-robot arm is reported beside it either way.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

__all__ = [
    "ARMS",
    "ARM_ARGS",
    "GAMMA_MS",
    "LINKS",
    "RUNS",
    "SPLIT",
    "WARMUP_S",
    "WHOLE_ARMS",
    "WINDOW_S",
    "Counters",
    "Window",
    "schedule",
    "summary",
    "verdict",
]

SPLIT, WHOLE_EDGE, WHOLE_ROBOT = "split", "whole-edge", "whole-robot"
ARMS = (SPLIT, WHOLE_EDGE, WHOLE_ROBOT)
WHOLE_ARMS = (WHOLE_EDGE, WHOLE_ROBOT)
ARM_ARGS: dict[str, list[str]] = {
    SPLIT: [],
    WHOLE_EDGE: ["module", "--whole", "edge"],
    WHOLE_ROBOT: ["module", "--whole", "robot"],
}
FAST, SLOW = "fast", "slow"
LINKS: dict[str, dict[str, float]] = {FAST: {}, SLOW: {"rate_mbit": 5.0, "delay_ms": 15.0}}
GAMMA_MS = 6.0
RUNS = 3
WARMUP_S = 20.0
WINDOW_S = 30.0
TARGET_REDUCTION = 0.5


def schedule(runs: int = RUNS) -> list[tuple[int, str]]:
    """(block, arm) in run order: every arm once per block, the order rotated by one a block."""
    return [(b, ARMS[(b + k) % len(ARMS)]) for b in range(runs) for k in range(len(ARMS))]


@dataclass(frozen=True)
class Counters:
    """One scrape of the head's counters."""

    frames: float  # fogfleet_dnn_frames_total, every action and answerer
    late: float  # fogfleet_dnn_late_frames_total
    local: float  # frames the local model answered (as the action or after a timeout)
    robot_s: float  # fogfleet_dnn_robot_seconds_total
    frame_s: float  # fogfleet_dnn_frame_seconds_sum


@dataclass(frozen=True)
class Window:
    """One arm at one link setting, between two scrapes ``seconds`` apart."""

    block: int
    arm: str
    link: str
    seconds: float
    cycle_s: float
    frames: float
    late: float
    local: float
    robot_s: float
    frame_s: float
    action: str  # what the head ran at the window's end

    @classmethod
    def between(
        cls, before: Counters, after: Counters, *, block: int, arm: str, link: str,
        seconds: float, cycle_s: float, action: str,
    ) -> Window:  # fmt: skip
        return cls(
            block, arm, link, seconds, cycle_s,
            frames=after.frames - before.frames,
            late=after.late - before.late,
            local=after.local - before.local,
            robot_s=after.robot_s - before.robot_s,
            frame_s=after.frame_s - before.frame_s,
            action=action,
        )  # fmt: skip

    @property
    def over_alpha(self) -> float:
        """The camera's frames in the window not answered within alpha (never below 0: a
        window may hold a frame more than its length at the cycle)."""
        return max(0.0, self.seconds / self.cycle_s - (self.frames - self.late))

    @property
    def robot_ms(self) -> float:
        """The robot's compute per answered frame, milliseconds."""
        return 1e3 * self.robot_s / self.frames if self.frames else float("nan")

    @property
    def frame_ms(self) -> float:
        return 1e3 * self.frame_s / self.frames if self.frames else float("nan")

    @property
    def local_share(self) -> float:
        return self.local / self.frames if self.frames else float("nan")

    def as_json(self) -> dict[str, Any]:
        return asdict(self) | {"overAlpha": self.over_alpha, "robotMillis": self.robot_ms}


def _median(values: Sequence[float]) -> float:
    finite = [v for v in values if v == v]
    return statistics.median(finite) if finite else float("nan")


def summary(windows: Sequence[Window]) -> dict[str, dict[str, dict[str, Any]]]:
    """link -> arm -> medians over its runs: frames over alpha, answered, local share, frame
    and robot milliseconds, runs, and the actions the head ended its windows on."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for link in LINKS:
        for arm in ARMS:
            ws = [w for w in windows if w.link == link and w.arm == arm]
            if not ws:
                continue
            out.setdefault(link, {})[arm] = {
                "runs": len(ws),
                "overAlpha": _median([w.over_alpha for w in ws]),
                "overAlphaRuns": [w.over_alpha for w in ws],
                "frames": _median([w.frames for w in ws]),
                "localShare": _median([w.local_share for w in ws]),
                "frameMillis": _median([w.frame_ms for w in ws]),
                "robotMillis": _median([w.robot_ms for w in ws]),
                "actions": sorted({w.action for w in ws}),
            }
    return out


def verdict(
    summ: Mapping[str, Mapping[str, Mapping[str, Any]]], link: str = SLOW
) -> dict[str, Any]:
    """The target at ``link``: the best whole arm within the robot budget, the split's
    reduction of its frames over alpha, and whether it is at least ``TARGET_REDUCTION``."""
    arms = summ.get(link, {})
    within = [a for a in WHOLE_ARMS if a in arms and arms[a]["robotMillis"] <= GAMMA_MS]
    out: dict[str, Any] = {"link": link, "gammaMillis": GAMMA_MS, "wholeWithinBudget": within}
    if SPLIT not in arms or not within:
        return out | {"best": None, "reduction": None, "met": False}
    best = min(within, key=lambda a: arms[a]["overAlpha"])
    control, treated = arms[best]["overAlpha"], arms[SPLIT]["overAlpha"]
    reduction = None if control == 0 else 1.0 - treated / control
    split_within = arms[SPLIT]["robotMillis"] <= GAMMA_MS
    met = reduction is not None and reduction >= TARGET_REDUCTION and split_within
    return out | {
        "best": best,
        "reduction": reduction,
        "splitWithinBudget": split_within,
        "met": met,
    }
