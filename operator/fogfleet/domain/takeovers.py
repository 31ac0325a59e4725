"""What the on-board standbys did: their takeovers, counted from their own counters (issue 44;
pure).

Each standby pod counts its takeovers (``fogfleet_fallback_takeovers_total``), keeps the gap of
the last one (``fogfleet_fallback_takeover_gap_seconds``: from the remote's last output to its
own first output) and when it took over (``fogfleet_fallback_last_takeover_timestamp_seconds``,
by its own clock; a workload built before it has none). The operator reads them
after each link measurement (``controllers.links``) and compares each counter with the value it
read before (``new_takeovers``):

- the first reading after the operator starts is a baseline: what the counters held before is
  already in the fleet's status (``status.fallbacks[].takeovers``), read back from there;
- a counter that rose by n: n takeovers;
- a counter that restarted (its ``_created`` time changed, or it went down: the standby's
  container restarted) counts from 0: its whole value is new;
- a series not seen before (a new standby pod) counts from 0 too;
- a series that vanished is remembered for ``MARK_KEEP_SECONDS``: while its robot's link is cut
  Prometheus cannot scrape it, and when it comes back its counter goes on from where it was
  (counting it from 0 again would count the cut's takeover twice).

A standby on a cut-off robot is not scraped, so its takeover is seen when the link returns:
its timestamp says when it happened (a workload without it: when the operator saw it).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

__all__ = [
    "MARK_KEEP_SECONDS",
    "Mark",
    "SeriesKey",
    "StandbySeries",
    "Takeovers",
    "advance_takeovers",
    "format_gap",
    "new_takeovers",
    "record_takeovers",
    "takeover_message",
]

MARK_KEEP_SECONDS = 86_400.0  # a vanished series' last value is kept this long
SeriesKey = tuple[str, ...]  # what tells one standby's series from another's (its pod's labels)
Standby = tuple[str, str]  # (robot, module)


@dataclass(frozen=True)
class StandbySeries:
    """One standby's counters as Prometheus shows them now."""

    robot: str
    module: str
    key: SeriesKey
    count: float  # takeovers since the counter started
    created: float | None = None  # when the counter started (a restart changes it)
    gap: float | None = None  # seconds, the last takeover's (0 or None: no own output yet)
    at: float | None = None  # Unix time of the last takeover, by the standby's clock


@dataclass(frozen=True)
class Mark:
    """A counter as last read."""

    count: float
    created: float | None
    seen: float  # when it was last read (the caller's clock)


@dataclass(frozen=True)
class Takeovers:
    """What one standby (robot, module) did, as the fleet's status keeps it."""

    count: int  # takeovers the operator saw
    last_gap: float | None = None  # seconds, of the last one
    last_time: float | None = None  # Unix time of the last one


def _restarted(mark: Mark, s: StandbySeries) -> bool:
    moved = s.created is not None and mark.created is not None and abs(s.created - mark.created)
    return s.count < mark.count or bool(moved and moved > 1e-3)


def new_takeovers(
    marks: Mapping[SeriesKey, Mark] | None, series: Iterable[StandbySeries], now: float
) -> tuple[dict[SeriesKey, Mark], dict[Standby, tuple[int, StandbySeries]]]:
    """The counters' new marks, and per standby (robot, module) the takeovers since the last
    reading with the series that holds the newest one. ``marks`` None: the first reading (a
    baseline, nothing is new)."""
    latest: dict[SeriesKey, StandbySeries] = {}
    for s in series:  # one pod scraped twice (two jobs): the same counter, read once
        if s.key not in latest or s.count > latest[s.key].count:
            latest[s.key] = s
    out: dict[SeriesKey, Mark] = {
        k: m
        for k, m in (marks or {}).items()
        if k not in latest and now - m.seen < MARK_KEEP_SECONDS
    }
    new: dict[Standby, tuple[int, StandbySeries]] = {}
    for key, s in sorted(latest.items()):
        out[key] = Mark(s.count, s.created, now)
        if marks is None:
            continue
        mark = marks.get(key)
        # a new or restarted counter counted from 0
        fresh = mark is None or _restarted(mark, s)
        n = round(s.count) if fresh or mark is None else round(s.count - mark.count)
        if n <= 0:
            continue
        who = (s.robot, s.module)
        before = new.get(who)
        if before is None:
            new[who] = (n, s)
        else:  # two pods of one standby (a rollout): the newest takeover is the last
            newer = (s.at or 0.0) >= (before[1].at or 0.0)
            new[who] = (before[0] + n, s if newer else before[1])
    return out, new


def record_takeovers(
    prev: Takeovers | None, new: int, last: StandbySeries | None, now: float
) -> Takeovers | None:
    """A standby's record after one reading: ``new`` takeovers, the newest in ``last``.
    Without new ones, a gap its series shows for the last one once the standby has published
    (its first own output may come a scrape after the counter) fills in a gap not known yet."""
    if new > 0:
        gap = last.gap if last is not None and last.gap else None
        at = last.at if last is not None and last.at else now
        return Takeovers((prev.count if prev else 0) + new, gap, at)
    if prev is not None and prev.last_gap is None and last is not None and last.gap:
        same = last.at is None or prev.last_time is None or abs(last.at - prev.last_time) < 1
        if same:
            return Takeovers(prev.count, last.gap, prev.last_time)
    return prev


def format_gap(seconds: float) -> str:
    """A takeover's gap as people read it: ``0.41 s``, ``12 s``."""
    return f"{seconds:.2f} s" if seconds < 10 else f"{seconds:.0f} s"


def takeover_message(robot: str, module: str, new: int, gap: float | None) -> str:
    """The StandbyTookOver Event's text."""
    times = "" if new <= 1 else f" {new} times, the last"
    if gap is None:
        return (
            f"the standby of {module} on {robot} took over{times} (its first own output is not "
            "measured yet)"
        )
    return (
        f"the standby of {module} on {robot} took over{times} {format_gap(gap)} after the "
        "remote's last output"
    )


def advance_takeovers(
    marks: Mapping[SeriesKey, Mark] | None,
    records: Mapping[Standby, Takeovers],
    series: Iterable[StandbySeries],
    now: float,
) -> tuple[dict[SeriesKey, Mark], dict[Standby, Takeovers]]:
    """One reading of a fleet's standbys: the counters' new marks and each standby's record
    (``new_takeovers``, then ``record_takeovers``)."""
    series = list(series)
    marks_after, new = new_takeovers(marks, series, now)
    newest: dict[Standby, StandbySeries] = {}
    for s in series:
        who, have = (s.robot, s.module), newest.get((s.robot, s.module))
        if have is None or (s.at or 0.0, s.created or 0.0) > (have.at or 0.0, have.created or 0.0):
            newest[who] = s
    out = dict(records)
    for who in sorted(set(new) | set(newest)):
        n, last = new.get(who, (0, newest.get(who)))
        got = record_takeovers(records.get(who), n, last, now)
        if got is not None:
            out[who] = got
    return marks_after, out
