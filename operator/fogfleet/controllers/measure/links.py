"""The robots' links as Prometheus sees them, and what the fleets report of them (issue 13).

Every ``period_seconds`` the operator asks Prometheus, for the robot nodes of every fleet it
rendered, what share of the scrapes of the robot's pods was answered over the fleet's window
and how fast the fastest answer came (``domain.linkhealth`` judges that against the robot's
ComputeNode), which on-board standbys compute their module now
(``fogfleet_fallback_active``), and what the standbys' own counters say of their takeovers
(``domain.takeovers``: how many, the last one's gap and time). A fleet whose planned links,
link states, active standbys or takeovers changed is reconciled: the planner then uses the
measured link of a degraded robot, and the status says what each robot's link is
(``status.links``, the ``Degraded`` condition, Events) and what its standbys did
(``status.fallbacks[].takeovers``, a ``StandbyTookOver`` Event per takeover).

Prometheus must label each pod target with its Kubernetes Node (``node``, as kubernetes_sd's
usual relabelling of ``__meta_kubernetes_pod_node_name`` does; FOGFLEET_LINK_NODE_LABEL).
When Prometheus cannot be reached, the last states stand and a warning is logged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet.adapters.ports import SeriesPort
from fogfleet.api.loader import Catalog
from fogfleet.api.timestamps import parse_timestamp, timestamp
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.linkhealth import LinkState
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.state import FleetKey, LinkWatch
from fogfleet.domain.linkhealth import (
    LinkSample,
    RobotLink,
    advance,
    judge,
    millis,
)
from fogfleet.domain.network import uplink
from fogfleet.domain.problem import Problem
from fogfleet.domain.takeovers import (
    StandbySeries,
    Takeovers,
    advance_takeovers,
    takeover_message,
)
from fogfleet.errors import DependencyUnavailable

__all__ = [
    "LinkDeps",
    "LinkReport",
    "link_events",
    "link_report",
    "link_watch",
    "measure_links",
    "takeover_events",
    "takeovers_from_status",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
FIELD = "status.links"
# one query per measure for all robots (their Nodes as a regex alternation)
ANSWERED = 'avg by ({label}) (avg_over_time(up{{{label}=~"{nodes}"}}[{window}s]))'
ROUND_TRIP = (
    'min by ({label}) (min_over_time(scrape_duration_seconds{{{label}=~"{nodes}"}}[{window}s]))'
)
ACTIVE = 'max by (robot, module) (fogfleet_fallback_active{{namespace="{namespace}"}})'
# the standbys' own takeover counters, per pod, in one query per namespace
TAKEOVERS = (
    '{{__name__=~"fogfleet_fallback_(takeovers_total|takeovers_created|takeover_gap_seconds'
    '|last_takeover_timestamp_seconds)",namespace="{namespace}"}}'
)


@dataclass
class LinkDeps:
    prometheus: SeriesPort
    node_label: str = "node"
    period_seconds: float = 10.0


def link_watch(fleet: RobotFleet, problem: Problem, catalog: Catalog) -> LinkWatch:
    """What the measurements need of a fleet's full pass: its robots' Nodes and declared
    uplinks, its settings, its modules."""
    robots = {
        nd.name: (nd.node_name, uplink(catalog.nodes[nd.name].spec))
        for nd in problem.nodes
        if nd.tier is Tier.ROBOT and nd.name in catalog.nodes
    }
    modules = frozenset(m.name for m in fleet.spec.modules)
    return LinkWatch(robots, fleet.spec.link_health, modules)


def measure_links(deps: Deps, links: LinkDeps, now: float) -> set[FleetKey]:
    """One round of measurements for every monitored fleet; the fleets whose link states,
    planned links or active standbys changed (to be reconciled)."""
    fleets = {
        s.key: (s, s.links.watch)
        for s in deps.store.states()
        if s.links.watch is not None and s.links.watch.monitored
    }
    if not fleets:
        return set()
    watches = {key: watch for key, (_, watch) in fleets.items() if watch is not None}
    try:
        by_window = _samples(links, watches)
        active = _active(links, {key[0] for key in fleets})
        standby_series = _standby_series(links, {key[0] for key in fleets})
    except DependencyUnavailable as exc:
        log.warning("Measuring the robots' links failed (last states stand): %s", exc)
        return set()
    changed: set[FleetKey] = set()
    for key, (state, watch) in fleets.items():
        assert watch is not None and watch.settings is not None
        settings = watch.settings
        samples = by_window[settings.window_seconds]
        before = state.links.robots
        after: dict[str, RobotLink] = {}
        for robot, (node, declared) in watch.robots.items():
            sample = samples.get(node, LinkSample(None, None))
            verdict = judge(robot, sample, declared, settings)
            after[robot] = advance(
                before.get(robot),
                verdict,
                sample,
                now,
                float(settings.stable_seconds),
                float(settings.window_seconds),
            )
            if before.get(robot) is None or before[robot].state is not after[robot].state:
                log.info("RobotFleet %s/%s: link %s: %s", *key, after[robot].state, verdict.message)
        robots = set(watch.robots)
        standbys = frozenset(
            (r, m) for ns, r, m in active if ns == key[0] and r in robots and m in watch.modules
        )
        state.links.robots = after
        if _summary(before) != _summary(after) or state.links.standbys_active != standbys:
            changed.add(key)
        state.links.standbys_active = standbys
        mine = [
            s
            for s in standby_series.get(key[0], [])
            if s.robot in robots and s.module in watch.modules
        ]
        records = state.links.takeovers or {}
        state.links.marks, took = advance_takeovers(state.links.marks, records, mine, now)
        if took != records:
            changed.add(key)
            for (robot, module), t in sorted(took.items()):
                if records.get((robot, module)) != t:
                    log.info("RobotFleet %s/%s: standby of %s on %s: %s", *key, module, robot, t)
        state.links.takeovers = took
    return changed


def _summary(links: Mapping[str, RobotLink]) -> dict[str, tuple[Any, ...]]:
    return {r: (rl.state, rl.planned, rl.message) for r, rl in links.items()}


def _samples(
    links: LinkDeps, fleets: Mapping[FleetKey, LinkWatch]
) -> dict[int, dict[str, LinkSample]]:
    """Per window length: node -> what Prometheus saw of it."""
    windows: dict[int, set[str]] = {}
    for watch in fleets.values():
        assert watch.settings is not None
        windows.setdefault(watch.settings.window_seconds, set()).update(
            node for node, _ in watch.robots.values()
        )
    out: dict[int, dict[str, LinkSample]] = {}
    for window, nodes in windows.items():
        # Node names are DNS subdomains: only the dot is special in a regex (escaped once for
        # the regex and once for PromQL's string literal)
        alternation = "|".join(n.replace(".", "\\\\.") for n in sorted(nodes))
        args = {"label": links.node_label, "nodes": alternation, "window": window}
        answered = _by_label(links, ANSWERED.format(**args), links.node_label)
        fastest = _by_label(links, ROUND_TRIP.format(**args), links.node_label)
        out[window] = {
            n: LinkSample(answered.get(n), fastest.get(n) if answered.get(n) else None)
            for n in nodes
        }
    return out


def _by_label(links: LinkDeps, promql: str, label: str) -> dict[str, float]:
    series = links.prometheus.query_series(promql, obj="links", field=FIELD)
    return {labels[label]: value for labels, value in series if label in labels}


def _active(links: LinkDeps, namespaces: set[str]) -> set[tuple[str, str, str]]:
    """(namespace, robot, module) of the standbys that compute on board now."""
    out: set[tuple[str, str, str]] = set()
    for ns in sorted(namespaces):
        promql = ACTIVE.format(namespace=ns.replace("\\", "\\\\").replace('"', '\\"'))
        for labels, value in links.prometheus.query_series(promql, obj="links", field=FIELD):
            if value >= 1 and "robot" in labels and "module" in labels:
                out.add((ns, labels["robot"], labels["module"]))
    return out


def _standby_series(links: LinkDeps, namespaces: set[str]) -> dict[str, list[StandbySeries]]:
    """Per namespace, each standby pod's takeover counters (one series per pod)."""
    out: dict[str, list[StandbySeries]] = {}
    for ns in sorted(namespaces):
        promql = TAKEOVERS.format(namespace=ns.replace("\\", "\\\\").replace('"', '\\"'))
        by_pod: dict[tuple[str, ...], dict[str, float]] = {}
        for labels, value in links.prometheus.query_series(promql, obj="links", field=FIELD):
            if "robot" not in labels or "module" not in labels:
                continue
            pod = labels.get("pod") or labels.get("instance", "")
            key = (labels["robot"], labels["module"], pod, labels.get("job", ""))
            by_pod.setdefault(key, {})[labels.get("__name__", "")] = value
        series = out.setdefault(ns, [])
        for (robot, module, pod, _), values in sorted(by_pod.items()):
            count = values.get("fogfleet_fallback_takeovers_total")
            if count is None:
                continue
            series.append(
                StandbySeries(
                    robot,
                    module,
                    (robot, module, pod),
                    count,
                    values.get("fogfleet_fallback_takeovers_created"),
                    values.get("fogfleet_fallback_takeover_gap_seconds"),
                    values.get("fogfleet_fallback_last_takeover_timestamp_seconds"),
                )
            )
    return out


def takeovers_from_status(status: Mapping[str, Any]) -> dict[tuple[str, str], Takeovers]:
    """What a fleet's status says its standbys did (read back after a restart or failover)."""
    out: dict[tuple[str, str], Takeovers] = {}
    for entry in status.get("fallbacks") or []:
        for t in entry.get("takeovers") or []:
            if t.get("count"):
                gap = t.get("lastGapSeconds")
                out[(str(entry.get("robot")), str(t.get("module")))] = Takeovers(
                    int(t["count"]),
                    None if gap is None else float(gap),
                    parse_timestamp(t.get("lastTakeoverTime")),
                )
    return out


# ---------------------------------------------------------------------------- the fleet's status
@dataclass(frozen=True)
class LinkReport:
    entries: list[Obj]  # status.links
    degraded: tuple[str, str] | None  # the Degraded condition's reason and message, if any
    # what the standbys did (None: not watched, the fleet's links are not monitored)
    takeovers: Mapping[tuple[str, str], Takeovers] | None = None
    active: frozenset[tuple[str, str]] = frozenset()  # (robot, module) computing on board

    def takeovers_of(self, robot: str, standbys: list[str]) -> list[Obj] | None:
        """``status.fallbacks[].takeovers`` of ``robot``: its standbys and any other module
        whose standby took over (None: not watched)."""
        if self.takeovers is None:
            return None
        modules = set(standbys) | {m for r, m in self.takeovers if r == robot}
        out: list[Obj] = []
        for module in sorted(modules):
            t = self.takeovers.get((robot, module))
            gap = t.last_gap if t is not None else None
            entry: Obj = {
                "module": module,
                "count": t.count if t is not None else 0,
                "lastGapSeconds": None if gap is None else round(gap, 3),
                "lastTakeoverTime": timestamp(t.last_time) if t and t.last_time else None,
                "active": (robot, module) in self.active,
            }
            out.append({k: v for k, v in entry.items() if v is not None})
        return out


def link_report(
    watch: LinkWatch | None,
    links: Mapping[str, RobotLink] | None,
    standbys: frozenset[tuple[str, str]] | None,
    takeovers: Mapping[tuple[str, str], Takeovers] | None = None,
) -> LinkReport:
    """``status.links`` and what the links make of the Degraded condition."""
    if links is None or watch is None or watch.settings is None or not watch.settings.monitor:
        return LinkReport([], None)
    active: dict[str, list[str]] = {}
    for robot, module in sorted(standbys or ()):
        active.setdefault(robot, []).append(module)
    entries: list[Obj] = []
    for robot, (_, declared) in sorted(watch.robots.items()):
        rl = links.get(robot)
        if rl is None:
            continue
        entry: Obj = {
            "robot": robot,
            "state": rl.state.value,
            "declaredLatencyMillis": millis(declared.latency),
            "measuredLatencyMillis": millis(rl.sample.one_way),
            "answeredPercent": (
                None if rl.sample.answered is None else round(rl.sample.answered * 100, 1)
            ),
            "plannedLatencyMillis": millis(rl.planned.latency) if rl.planned else None,
            "since": timestamp(rl.since),
            "standbysActive": active.get(robot, []),
            "message": rl.message,
        }
        entries.append({k: v for k, v in entry.items() if v is not None})
    return LinkReport(
        entries, _degraded(links, active), dict(takeovers or {}), frozenset(standbys or ())
    )


def _degraded(
    links: Mapping[str, RobotLink], active: Mapping[str, list[str]]
) -> tuple[str, str] | None:
    lost = sorted(r for r, rl in links.items() if rl.state is LinkState.LOST)
    bad = sorted(
        r for r, rl in links.items() if rl.state in (LinkState.DEGRADED, LinkState.RECOVERING)
    )
    parts: list[str] = []
    if lost:
        parts.append(
            f"link lost to {', '.join(lost)}: on-board standbys take over, nothing is moved"
        )
    for r in bad:
        rl = links[r]
        recovering = rl.state is LinkState.RECOVERING  # its message says it already
        parts.append(rl.message if recovering else f"{rl.message}: planned with the measured link")
    if active:
        parts.append(
            "standbys computing on board: "
            + "; ".join(f"{r}: {', '.join(ms)}" for r, ms in sorted(active.items()))
        )
    if not parts:
        return None
    reason = "LinkLost" if lost else ("LinkDegraded" if bad else "FallbackActive")
    return reason, "; ".join(parts)


EVENT_OF = {
    LinkState.LOST: ("Warning", "LinkLost"),
    LinkState.DEGRADED: ("Warning", "LinkDegraded"),
    LinkState.RECOVERING: ("Normal", "LinkRecovering"),
    LinkState.HEALTHY: ("Normal", "LinkHealthy"),
}


def link_events(old: list[Obj], new: list[Obj]) -> list[tuple[str, str, str]]:
    """(type, reason, message) for each robot whose link state changed since the last status
    (a first Healthy or Unknown is no news), and for standbys that started computing."""
    before = {str(e.get("robot")): e for e in old or []}
    out: list[tuple[str, str, str]] = []
    for e in new:
        prev = before.get(e["robot"], {})
        state = LinkState(e["state"])
        first_quiet = not prev and state in (LinkState.HEALTHY, LinkState.UNKNOWN)
        if prev.get("state") != e["state"] and not first_quiet and state in EVENT_OF:
            kind, reason = EVENT_OF[state]
            out.append((kind, reason, e["message"]))
        started = sorted(set(e.get("standbysActive", [])) - set(prev.get("standbysActive", [])))
        if started:
            out.append(
                (
                    "Warning",
                    "FallbackActive",
                    f"{e['robot']}: the on-board standby of {', '.join(started)} computes "
                    "its outputs (the remote instance went silent)",
                )
            )
    return out


def takeover_events(old: list[Obj], new: list[Obj]) -> list[tuple[str, str, str]]:
    """A StandbyTookOver Event per standby whose takeovers rose since the last status
    (``status.fallbacks``). A robot whose takeovers were not listed before (its standbys not
    watched yet, or the robot not offloaded) starts from its new count: its earlier takeovers
    were reported when they came."""
    before = {
        str(f.get("robot")): {str(t.get("module")): int(t.get("count") or 0) for t in ts}
        for f in old or []
        if (ts := f.get("takeovers")) is not None
    }
    out: list[tuple[str, str, str]] = []
    for f in new:
        robot = str(f.get("robot"))
        if robot not in before:
            continue
        for t in f.get("takeovers") or []:
            n = int(t.get("count") or 0) - before[robot].get(str(t["module"]), 0)
            if n > 0:
                gap = t.get("lastGapSeconds")
                message = takeover_message(robot, str(t["module"]), n, gap)
                out.append(("Normal", "StandbyTookOver", message))
    return out
