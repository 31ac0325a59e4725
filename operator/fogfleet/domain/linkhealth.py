"""A robot's link as measured, judged against its ComputeNode's figures (issue 13; pure).

The measurement is what the control plane sees of the robot's pods across the link (the
adapter reads it from Prometheus): the share of scrapes answered in a window, and the fastest
answered scrape, which is one round trip over keep-alive plus the exporter's own time. Half
of it bounds the one-way latency from above, like ping's minimum; retransmissions after loss
and a busy exporter raise the slow scrapes, not the fastest one, so the estimate does not
chase noise. (The fogfleet workload keeps its connection alive and gzips its answer; an
exporter that closes the connection after each scrape costs a second round trip, and its
robot's link reads up to twice as slow as it is.)

Judging (``judge``) and remembering (``advance``) are separate so that each is tested alone:

- no scrape answered in the window: **Lost**. Nothing is re-planned: a robot cut off cannot
  receive new pods (its kubelet cannot reach the API server) and its standbys take over by
  themselves (RoboEC2's local path);
- answered, but slower than ``latencyFactor`` x declared + ``latencyMarginMillis``, or fewer
  answers than ``minAnsweredPercent``: **Degraded**. The fleet is planned with the measured
  link in place of the declared one (eq. 4's transfer then charges what the link costs), so
  the planner moves what suffers on board where it fits. Either counts only once it has
  lasted a whole window: every cut begins and ends with windows of too few answers, and the
  first scrapes of a pod that has just started are slow (its exporter still starting: on the
  bed the first window of a new fleet read 40-112 ms one way over a 4 ms link, and the next
  one 10-15 ms), which would move modules for nothing and keep them moved for the stable
  window;
- healthy after Degraded: **Recovering** (still planned with the measured link) until healthy
  for ``stableSeconds``, then **Healthy** and planned as declared again: modules move back
  only after a stable window, and a link that flaps stays re-planned around.

The planned link only gets worse while Degraded when the measure is 1.5 times the planned
one: small changes in the measure do not re-plan the fleet each window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from fogfleet.api.v1alpha1.base import parse_millis, parse_quantity
from fogfleet.api.v1alpha1.linkhealth import LinkHealth, LinkState

from .network import Link

__all__ = [
    "LinkSample",
    "RobotLink",
    "Verdict",
    "advance",
    "judge",
    "latency_limit",
    "millis",
    "planned_links",
]

WORSE = 1.5  # a degraded link's planned latency follows the measure only past this factor


@dataclass(frozen=True)
class LinkSample:
    """What one window showed of a robot's link (None: no pod of the robot was scraped)."""

    answered: float | None  # share of scrapes answered (0-1)
    round_trip: float | None  # seconds: the fastest answered scrape

    @property
    def one_way(self) -> float | None:
        return None if self.round_trip is None else self.round_trip / 2


@dataclass(frozen=True)
class Verdict:
    state: LinkState  # HEALTHY, DEGRADED, LOST or UNKNOWN: what this window says
    measured: Link | None  # the link as measured (for the planner), when answered
    message: str
    slow: bool = False  # DEGRADED by its latency (else by its share of answers alone)


def latency_limit(declared: Link, settings: LinkHealth) -> float:
    """Seconds of one-way latency above which the link is degraded."""
    factor = parse_quantity(settings.latency_factor)
    return factor * declared.latency + parse_millis(settings.latency_margin_millis)


def judge(robot: str, sample: LinkSample, declared: Link, settings: LinkHealth) -> Verdict:
    """One window's verdict on ``robot``'s link."""
    if sample.answered is None:
        return Verdict(LinkState.UNKNOWN, None, f"{robot}: none of its pods is scraped")
    if sample.answered <= 0 or sample.one_way is None:
        return Verdict(
            LinkState.LOST,
            None,
            f"{robot} answered none of its scrapes for {settings.window_seconds} s",
        )
    one_way, answered = sample.one_way, sample.answered
    measured = Link(
        latency=max(declared.latency, one_way),
        jitter=declared.jitter,
        bandwidth=declared.bandwidth,
        loss=max(declared.loss, 1.0 - answered),
    )
    limit = latency_limit(declared, settings)
    seen = (
        f"{robot}'s link measured {one_way * 1e3:.0f} ms one way "
        f"(declared {declared.latency * 1e3:g} ms, limit {limit * 1e3:.0f} ms), "
        f"{answered * 100:.0f}% of scrapes answered"
    )
    if one_way > limit or answered * 100 < settings.min_answered_percent:
        return Verdict(LinkState.DEGRADED, measured, seen, slow=one_way > limit)
    return Verdict(LinkState.HEALTHY, measured, seen)


@dataclass(frozen=True)
class RobotLink:
    """What the fleet remembers of one robot's link between windows."""

    state: LinkState
    since: float  # when this state began (seconds, the caller's clock)
    planned: Link | None  # the link the planner uses instead of the declared one
    message: str
    sample: LinkSample
    healthy_since: float | None = None  # Recovering: since when the windows say healthy
    sparse_since: float | None = None  # since when the windows lack answers (latency fine)
    slow_since: float | None = None  # since when the windows are too slow (not planned yet)


def advance(
    prev: RobotLink | None,
    verdict: Verdict,
    sample: LinkSample,
    now: float,
    stable: float,
    window: float = 0.0,
) -> RobotLink:
    """The link's state after one more window of ``window`` seconds (see the module
    docstring). Too few answers at a fine latency count only once they have lasted a whole
    window: a window that overlaps a cut, as it begins or ends, holds some unanswered
    scrapes, and re-planning a robot as its link goes would move pods it cannot receive. A
    link not planned around yet counts as slow once it has been for a whole window too (the
    first scrapes of new pods are slow); one planned around follows its measure at once."""
    planned = prev.planned if prev is not None else None

    def to(new: LinkState, link: Link | None, msg: str, healthy: float | None = None) -> RobotLink:
        since = prev.since if prev is not None and prev.state is new else now
        return RobotLink(new, since, link, msg, sample, healthy)

    if verdict.state is LinkState.DEGRADED and not verdict.slow:
        sparse = prev.sparse_since if prev is not None and prev.sparse_since is not None else now
        if now - sparse < window:  # not yet a whole window of it: hold what we knew
            if prev is None:
                return RobotLink(LinkState.UNKNOWN, now, None, verdict.message, sample, None, now)
            return replace(prev, sample=sample, sparse_since=sparse)
        got = advance(prev, replace(verdict, slow=True), sample, now, stable)
        return replace(got, sparse_since=sparse)
    if verdict.state is LinkState.DEGRADED and verdict.slow and planned is None:
        slow = prev.slow_since if prev is not None and prev.slow_since is not None else now
        if now - slow < window:  # not yet a whole window of it: hold what we knew
            if prev is None:
                return RobotLink(LinkState.UNKNOWN, now, None, verdict.message, sample,
                                 slow_since=slow)  # fmt: skip
            return replace(prev, sample=sample, slow_since=slow)
    if verdict.state is LinkState.UNKNOWN:  # nothing measured: keep what we knew
        if prev is None:
            return to(LinkState.UNKNOWN, None, verdict.message)
        return replace(prev, sample=sample)
    if verdict.state is LinkState.LOST:
        return to(LinkState.LOST, planned, verdict.message)
    if verdict.state is LinkState.DEGRADED:
        assert verdict.measured is not None
        worse = planned is None or verdict.measured.latency > WORSE * planned.latency
        keep = verdict.measured if worse else planned
        if planned is not None and not worse:
            keep = replace(planned, loss=max(planned.loss, verdict.measured.loss))
        return to(LinkState.DEGRADED, keep, verdict.message)
    # healthy now
    if planned is None:
        return to(LinkState.HEALTHY, None, verdict.message)
    healthy = (
        prev.healthy_since
        if prev is not None and prev.state is LinkState.RECOVERING and prev.healthy_since
        else now
    )
    if now - healthy >= stable:
        return to(LinkState.HEALTHY, None, f"{verdict.message}; healthy for {now - healthy:.0f} s")
    msg = (
        f"{verdict.message}; planned with the measured link until healthy for {stable:.0f} s "
        f"({now - healthy:.0f} s so far)"
    )
    return to(LinkState.RECOVERING, planned, msg, healthy)


def planned_links(links: dict[str, RobotLink]) -> dict[str, Link]:
    """Robot -> the link the planner uses in place of the declared one."""
    return {r: rl.planned for r, rl in sorted(links.items()) if rl.planned is not None}


def millis(seconds: float | None) -> float | None:
    """Seconds as milliseconds rounded for a status (None and non-finite stay None)."""
    if seconds is None or not math.isfinite(seconds):
        return None
    return round(seconds * 1e3, 1)
