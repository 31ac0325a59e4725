"""The robots' links as Prometheus sees them, and what the fleets report of them (issue 13).

Every ``period_seconds`` the operator asks Prometheus, for the robot nodes of every fleet it
rendered, what share of the scrapes of the robot's pods was answered over the fleet's window
and how fast the fastest answer came (``domain.linkhealth`` judges that against the robot's
ComputeNode), and which on-board standbys compute their module now
(``fogfleet_fallback_active``). A fleet whose planned links, link states or active standbys
changed is reconciled: the planner then uses the measured link of a degraded robot, and the
status says what each robot's link is (``status.links``, the ``Degraded`` condition, Events).

Prometheus must label each pod target with its Kubernetes Node (``node``, as kubernetes_sd's
usual relabelling of ``__meta_kubernetes_pod_node_name`` does; FOGFLEET_LINK_NODE_LABEL).
When Prometheus cannot be reached, the last states stand and a warning is logged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.linkhealth import LinkState
from fogfleet.domain.linkhealth import (
    LinkSample,
    RobotLink,
    advance,
    judge,
    millis,
)
from fogfleet.errors import DependencyUnavailable

from .deps import Deps, FleetKey, Rendered

__all__ = [
    "LinkDeps",
    "LinkReport",
    "SeriesPort",
    "link_events",
    "link_report",
    "measure_links",
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


class SeriesPort(Protocol):
    def query_series(
        self, promql: str, *, obj: str = "", field: str = ""
    ) -> list[tuple[dict[str, str], float]]:
        """Every series of an instant query with its labels (NaN values left out)."""
        ...


@dataclass
class LinkDeps:
    prometheus: SeriesPort
    node_label: str = "node"
    period_seconds: float = 10.0


def measure_links(deps: Deps, links: LinkDeps, now: float) -> set[FleetKey]:
    """One round of measurements for every monitored fleet; the fleets whose link states,
    planned links or active standbys changed (to be reconciled)."""
    fleets = {
        key: r
        for key, r in list(deps.rendered.items())
        if r.robots and r.link_health is not None and r.link_health.monitor
    }
    # a fleet being reconciled right now is briefly missing from ``rendered``: its link states
    # stay (``robotfleet.forget`` drops them when the fleet goes)
    if not fleets:
        return set()
    try:
        by_window = _samples(links, fleets)
        active = _active(links, {key[0] for key in fleets})
    except DependencyUnavailable as exc:
        log.warning("Measuring the robots' links failed (last states stand): %s", exc)
        return set()
    changed: set[FleetKey] = set()
    for key, rendered in fleets.items():
        assert rendered.link_health is not None
        settings = rendered.link_health
        samples = by_window[settings.window_seconds]
        before = deps.links.get(key, {})
        after: dict[str, RobotLink] = {}
        for robot, (node, declared) in rendered.robots.items():
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
        robots = set(rendered.robots)
        standbys = frozenset(
            (r, m) for ns, r, m in active if ns == key[0] and r in robots and m in rendered.modules
        )
        deps.links[key] = after
        if _summary(before) != _summary(after) or deps.standbys_active.get(key) != standbys:
            changed.add(key)
        deps.standbys_active[key] = standbys
    return changed


def _summary(links: Mapping[str, RobotLink]) -> dict[str, tuple[Any, ...]]:
    return {r: (rl.state, rl.planned, rl.message) for r, rl in links.items()}


def _samples(
    links: LinkDeps, fleets: Mapping[FleetKey, Rendered]
) -> dict[int, dict[str, LinkSample]]:
    """Per window length: node -> what Prometheus saw of it."""
    windows: dict[int, set[str]] = {}
    for r in fleets.values():
        assert r.link_health is not None
        windows.setdefault(r.link_health.window_seconds, set()).update(
            node for node, _ in r.robots.values()
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


# ---------------------------------------------------------------------------- the fleet's status
@dataclass(frozen=True)
class LinkReport:
    entries: list[Obj]  # status.links
    degraded: tuple[str, str] | None  # the Degraded condition's reason and message, if any


def link_report(
    rendered: Rendered,
    links: Mapping[str, RobotLink] | None,
    standbys: frozenset[tuple[str, str]] | None,
) -> LinkReport:
    """``status.links`` and what the links make of the Degraded condition."""
    if links is None or rendered.link_health is None or not rendered.link_health.monitor:
        return LinkReport([], None)
    active: dict[str, list[str]] = {}
    for robot, module in sorted(standbys or ()):
        active.setdefault(robot, []).append(module)
    entries: list[Obj] = []
    for robot, (_, declared) in sorted(rendered.robots.items()):
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
    return LinkReport(entries, _degraded(links, active))


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
