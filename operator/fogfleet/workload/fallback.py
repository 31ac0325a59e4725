"""On-board fallback for an offloaded module: the standby's two decisions (no ROS here).

An offloaded module with a fallback runs twice: the **remote** instance (edge or cloud) does
the work and publishes each output ``T`` on ``T/remote``; the **standby** on the robot is the
only publisher of ``T`` itself. It relays the remote's outputs and, when they go silent,
computes them on board. RoboEC2 (roboec2-dnn-offloading) keeps such a local path for when the
network fails; here the switch needs no control plane (a robot cut off from the edge cannot
reach the API server either), so the standby decides alone:

- ``Takeover``: the remote is *silent* once no output of it has arrived for ``silent_cycles``
  cycle times; the standby then runs the module's cycles itself. It steps back once the remote
  has delivered without such a gap for ``step_back_cycles`` cycle times (hysteresis: a link
  that flickers does not make the standby flap).
- ``FirstResponse``: per output topic, the first answer to an input wins. A message that
  answers an input (its header's origin) already answered by the other source, or an older
  one, is dropped, so a slow link never puts two answers to one input on the robot's topic;
  a stream's repeats of its latest answer (same source, same origin) pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from fogfleet.contract.dnn import ROLE_HEAD, ROLE_TAIL
from fogfleet.contract.relay import remote_topic

__all__ = ["FirstResponse", "Role", "Source", "Takeover", "remote_topic"]


class Role(StrEnum):
    PRIMARY = "primary"  # no fallback: publishes its outputs itself
    REMOTE = "remote"  # offloaded, with a standby on its robot: publishes on T/remote
    STANDBY = "standby"  # on the robot: relays T/remote to T, or computes T when it is silent
    # a split DNN module (``python -m fogfleet.workload dnn``; workload.dnn.ros): no fallback of
    # this kind, its head holds the local model itself
    HEAD = ROLE_HEAD  # on the robot: frames, the head of the split, the rule, the local model
    TAIL = ROLE_TAIL  # off board: the tail of whatever split a frame names


class Source(StrEnum):
    REMOTE = "remote"
    STANDBY = "standby"


@dataclass
class Takeover:
    """Whether the standby runs the module now (times are ``time.monotonic()`` seconds)."""

    cycle_s: float
    silent_cycles: int = 3
    step_back_cycles: int = 10
    started: float = 0.0  # the standby's start: the remote has this long to be heard first
    active: bool = False
    takeovers: int = 0
    last_remote: float | None = None
    remote_back_since: float | None = None  # the remote's first output after a gap

    @property
    def silence_s(self) -> float:
        return self.silent_cycles * self.cycle_s

    def remote_output(self, now: float) -> None:
        """An output of the remote instance arrived."""
        if self.last_remote is None or now - self.last_remote > self.silence_s:
            self.remote_back_since = now
        self.last_remote = now

    def should_run(self, now: float) -> bool:
        """Decide at ``now``: True while the standby must compute the outputs itself."""
        heard = self.started if self.last_remote is None else self.last_remote
        silent = now - heard > self.silence_s
        if not self.active and silent:
            self.active = True
            self.takeovers += 1
        elif self.active and not silent:
            back = self.remote_back_since
            if back is not None and now - back >= self.step_back_cycles * self.cycle_s:
                self.active = False
        return self.active


@dataclass
class FirstResponse:
    """Per topic, the (source, origin) of the last message let through."""

    last: dict[str, tuple[Source, int]] = field(default_factory=dict)
    dropped: int = 0

    def claim(self, topic: str, source: Source, origin_ns: int) -> bool:
        """True if a message of ``source`` answering input ``origin_ns`` may go out on
        ``topic`` (and records it); False if the input was answered already or is older."""
        prev = self.last.get(topic)
        if prev is None or origin_ns > prev[1] or (origin_ns == prev[1] and source is prev[0]):
            self.last[topic] = (source, origin_ns)
            return True
        self.dropped += 1
        return False
