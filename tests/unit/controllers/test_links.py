"""The robots' links measured from Prometheus' series, and what a fleet does about them."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

import fogfleet.controllers.fleet.plan as fleet_plan
from fogfleet.api.timestamps import timestamp
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.measure.links import LinkDeps, link_events, measure_links, takeover_events
from fogfleet.errors import DependencyUnavailable

KEY = ("warehouse", "warehouse")
ROBOTS = [f"robot-{i}" for i in range(1, 6)]


class FakePrometheus:
    """SeriesPort: answers the link queries from per-node figures, records every query."""

    def __init__(self) -> None:
        self.answered = {r: 1.0 for r in ROBOTS}
        self.round_trip = {r: 0.010 for r in ROBOTS}  # 5 ms one way
        self.active: list[tuple[str, str]] = []
        self.standby: list[tuple[dict[str, str], float]] = []  # the takeover counters' series
        self.queries: list[str] = []
        self.down = False

    def query_series(
        self, promql: str, *, obj: str = "", field: str = ""
    ) -> list[tuple[dict[str, str], float]]:
        self.queries.append(promql)
        if self.down:
            raise DependencyUnavailable("Cannot query Prometheus at http://prom: refused")
        if promql.startswith("avg by (node)"):
            return [({"node": n}, v) for n, v in self.answered.items()]
        if promql.startswith("min by (node)"):
            return [({"node": n}, v) for n, v in self.round_trip.items()]
        if promql.startswith("{__name__"):
            return list(self.standby)
        return [({"robot": r, "module": m}, 1.0) for r, m in self.active]


@pytest.fixture
def prom() -> FakePrometheus:
    return FakePrometheus()


@pytest.fixture
def builds(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The measured links each full pass built its problem with."""
    seen: list[Any] = []
    real = fleet_plan.build

    def recording(snapshot: Any) -> Any:
        seen.append(dict(snapshot.measured_links))
        return real(snapshot)

    monkeypatch.setattr(fleet_plan, "build", recording)
    return seen


def run(kube: Any, deps: Any) -> Any:
    return reconcile(kube.get_fleet(*KEY), deps)


def status(kube: Any) -> dict[str, Any]:
    return dict(kube.fleets[KEY]["status"])


def degraded(kube: Any) -> dict[str, Any]:
    return next(c for c in status(kube)["conditions"] if c["type"] == "Degraded")


def links(kube: Any) -> dict[str, dict[str, Any]]:
    return {e["robot"]: e for e in status(kube).get("links", [])}


def measure(deps: Any, prom: FakePrometheus, now: float) -> set[Any]:
    return measure_links(deps, LinkDeps(prom), now)


def onboard(kube: Any, robot: str) -> set[str]:
    return {
        p["module"] for p in status(kube)["placement"] if p["robot"] == robot and p["node"] == robot
    }


def test_one_query_per_measure_asks_for_every_robot_node(kube, deps, prom) -> None:
    run(kube, deps)
    assert measure(deps, prom, 0) == {KEY}  # first measures: news for the status
    answered, fastest, active, takeovers = prom.queries
    for robot in ROBOTS:
        assert robot in answered and robot in fastest
    assert "up{node=~" in answered and "[30s]" in answered
    assert "scrape_duration_seconds" in fastest
    assert active == 'max by (robot, module) (fogfleet_fallback_active{namespace="warehouse"})'
    assert takeovers == (
        '{__name__=~"fogfleet_fallback_(takeovers_total|takeovers_created|takeover_gap_seconds'
        '|last_takeover_timestamp_seconds)",namespace="warehouse"}'
    )
    assert measure(deps, prom, 10) == set()  # nothing changed: nothing to reconcile


def test_healthy_links_are_reported_and_change_nothing(kube, deps, prom, builds) -> None:
    run(kube, deps)
    measure(deps, prom, 0)
    run(kube, deps)
    assert len(builds) == 1, "a status change alone must not rebuild the problem"
    got = links(kube)
    assert set(got) == set(ROBOTS)
    assert got["robot-1"]["state"] == "Healthy"
    assert got["robot-1"]["measuredLatencyMillis"] == 5.0
    assert got["robot-1"]["answeredPercent"] == 100.0
    assert "plannedLatencyMillis" not in got["robot-1"]
    assert degraded(kube)["status"] == "False"
    assert not [e for e in kube.events if e[1].startswith("Link")]


@pytest.mark.integration
def test_a_slow_link_re_plans_its_robot_with_the_measure_and_moves_back_when_stable(
    kube, deps, prom, builds
) -> None:
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    before = onboard(kube, "robot-1")
    measure(deps, prom, 0)
    prom.round_trip["robot-1"] = 1.0  # 500 ms one way: every offloaded cycle misses
    assert measure(deps, prom, 10) == set()  # slow for less than a window (30 s): held
    assert deps.store.state(KEY).links.robots["robot-1"].state.value == "Healthy"
    assert measure(deps, prom, 40) == {KEY}
    run(kube, deps)
    assert builds[-1].keys() == {"robot-1"}
    assert builds[-1]["robot-1"].latency == pytest.approx(0.5)
    after = onboard(kube, "robot-1")
    # its fast modules come on board (a slow one may leave to make room)
    assert len(after) > len(before), (before, after)
    entry = links(kube)["robot-1"]
    assert entry["state"] == "Degraded" and entry["plannedLatencyMillis"] == 500.0
    cond = degraded(kube)
    assert cond["status"] == "True" and cond["reason"] == "LinkDegraded"
    assert "robot-1's link measured 500 ms one way (declared" in cond["message"]
    assert ("Warning", "LinkDegraded") in {e[:2] for e in kube.events}
    assert links(kube)["robot-2"]["state"] == "Healthy"

    prom.round_trip["robot-1"] = 0.010  # healthy again: kept on board for the stable window
    stable = kube.fleets[KEY]["spec"].get("linkHealth", {}).get("stableSeconds", 120)
    assert measure(deps, prom, 50) == {KEY}
    run(kube, deps)
    assert links(kube)["robot-1"]["state"] == "Recovering"
    assert onboard(kube, "robot-1") == after and builds[-1].keys() == {"robot-1"}
    assert degraded(kube)["reason"] == "LinkDegraded"
    measure(deps, prom, 50 + stable)
    run(kube, deps)
    assert links(kube)["robot-1"]["state"] == "Healthy"
    assert builds[-1] == {}, "planned with the declared link again"
    # released from the migration margin, the robot's modules leave the robot again as the
    # plan with the declared link wants (the GA's own choice: not always the same modules)
    back = onboard(kube, "robot-1")
    assert len(back) < len(after), (before, after, back)
    assert ("Normal", "LinkHealthy") in {e[:2] for e in kube.events}
    assert degraded(kube)["status"] == "False" or degraded(kube)["reason"] == "Migrating"


def test_a_lost_link_is_reported_and_moves_nothing(kube, deps, prom, builds) -> None:
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    placement = status(kube)["placement"]
    measure(deps, prom, 0)
    prom.answered["robot-3"] = 0.0
    assert measure(deps, prom, 10) == {KEY}
    run(kube, deps)
    assert len(builds) == 1 and status(kube)["placement"] == placement
    cond = degraded(kube)
    assert cond["reason"] == "LinkLost"
    assert "link lost to robot-3: on-board standbys take over, nothing is moved" in cond["message"]
    assert links(kube)["robot-3"]["state"] == "Lost"
    assert "measuredLatencyMillis" not in links(kube)["robot-3"]
    assert ("Warning", "LinkLost") in {e[:2] for e in kube.events}


def test_a_standby_computing_on_board_makes_the_fleet_degraded(kube, deps, prom) -> None:
    run(kube, deps)
    measure(deps, prom, 0)
    module = kube.fleets[KEY]["spec"]["modules"][0]["name"]
    prom.active = [("robot-2", module), ("robot-2", "not-in-this-fleet"), ("robot-9", module)]
    assert measure(deps, prom, 10) == {KEY}
    run(kube, deps)
    cond = degraded(kube)
    assert cond["reason"] == "FallbackActive"
    assert f"standbys computing on board: robot-2: {module}" in cond["message"]
    assert links(kube)["robot-2"]["standbysActive"] == [module]
    assert any(e[1] == "FallbackActive" and module in e[2] for e in kube.events)


def test_prometheus_down_keeps_the_last_states(kube, deps, prom) -> None:
    run(kube, deps)
    prom.round_trip["robot-1"] = 1.0
    measure(deps, prom, 0)
    measure(deps, prom, 30)  # slow for a whole window
    prom.down = True
    assert measure(deps, prom, 40) == set()
    assert deps.store.state(KEY).links.robots["robot-1"].state.value == "Degraded"


def test_a_fleet_that_does_not_monitor_its_links_is_not_measured(kube, deps, prom) -> None:
    kube.fleets[KEY]["spec"]["linkHealth"] = {"monitor": False}
    run(kube, deps)
    assert measure(deps, prom, 0) == set() and prom.queries == []
    run(kube, deps)
    assert "links" not in status(kube) or status(kube)["links"] == []


def test_a_fleet_in_the_middle_of_a_reconcile_keeps_its_links_until_forgotten(
    kube, deps, prom
) -> None:
    run(kube, deps)
    prom.round_trip["robot-1"] = 1.0
    measure(deps, prom, 0)
    measure(deps, prom, 30)
    state = deps.store.state(KEY)
    state.rendered = None  # what a reconcile in another thread does for a moment
    measure(deps, prom, 40)
    assert state.links.robots["robot-1"].state.value == "Degraded"
    deps.store.forget(KEY)  # the fleet is gone
    assert deps.store.get(KEY) is None
    assert measure(deps, prom, 50) == set()


def test_link_events_report_changes_not_first_healthy_states() -> None:
    healthy = {"robot": "r1", "state": "Healthy", "message": "ok"}
    bad = {"robot": "r1", "state": "Degraded", "message": "slow"}
    assert link_events([], [healthy]) == []
    assert link_events([], [bad]) == [("Warning", "LinkDegraded", "slow")]
    assert link_events([bad], [bad]) == []
    assert link_events([bad], [{**bad, "state": "Recovering", "message": "better"}]) == [
        ("Normal", "LinkRecovering", "better")
    ]


def test_dots_in_node_names_are_escaped_for_the_regex_and_for_promql(kube, deps, prom) -> None:
    run(kube, deps)
    state = deps.store.state(KEY)
    assert state.links.watch is not None
    robot, node = next(iter(state.links.watch.robots.items()))
    robots = {robot: ("robot-1.site.example", node[1])}
    state.links.watch = dataclasses.replace(state.links.watch, robots=robots)
    measure(deps, prom, 0)
    assert 'up{node=~"robot-1\\\\.site\\\\.example"}' in prom.queries[0]


HPE = "human-pose-estimation"


def with_standbys(kube: Any, deps: Any) -> str:
    """The warehouse with human-pose-estimation offloaded behind an on-board standby; the
    first robot it is offloaded from."""
    hpe = kube.modules[("warehouse", HPE)]["spec"]
    hpe["fallback"], hpe["preferredTiers"] = {"mode": "onboard", "cpu": 1}, ["edge"]
    kube.fleets[KEY]["spec"].setdefault("scheduler", {})["migrationMarginPercent"] = 100
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    return next(f["robot"] for f in status(kube)["fallbacks"] if HPE in f["standbys"])


def counters(robot: str, count: float, created: float = 1e9, **kw: float) -> list[Any]:
    """What Prometheus holds of one standby pod's takeover counters."""
    labels = {"namespace": "warehouse", "pod": f"{robot}-hpe-standby", "job": "kubernetes-pods"}
    labels |= {"robot": robot, "module": HPE, "tier": "robot", "node": robot}
    values = {
        "fogfleet_fallback_takeovers_total": count,
        "fogfleet_fallback_takeovers_created": created,
        "fogfleet_fallback_takeover_gap_seconds": kw.get("gap", 0.0),
    }
    if "at" in kw:
        values["fogfleet_fallback_last_takeover_timestamp_seconds"] = kw["at"]
    return [({**labels, "__name__": name}, v) for name, v in values.items()]


def takeovers(kube: Any, robot: str) -> dict[str, dict[str, Any]]:
    entry = next(f for f in status(kube)["fallbacks"] if f["robot"] == robot)
    return {t["module"]: t for t in entry["takeovers"]}


def took_over(kube: Any) -> list[str]:
    return [e[2] for e in kube.events if e[1] == "StandbyTookOver"]


def test_a_standbys_takeover_is_in_the_status_and_one_event(kube, deps, prom) -> None:
    robot = with_standbys(kube, deps)
    prom.standby = counters(robot, 0)
    measure(deps, prom, 0)  # the first reading: a baseline
    run(kube, deps)
    assert takeovers(kube, robot)[HPE] == {"module": HPE, "count": 0, "active": False}
    assert took_over(kube) == []

    at = 1_790_000_000.0
    prom.standby = counters(robot, 1, gap=0.41, at=at)  # seen once the link is back
    assert measure(deps, prom, 10) == {KEY}
    run(kube, deps)
    assert takeovers(kube, robot)[HPE] == {
        "module": HPE,
        "count": 1,
        "lastGapSeconds": 0.41,
        "lastTakeoverTime": timestamp(at),
        "active": False,
    }
    assert took_over(kube) == [
        f"the standby of {HPE} on {robot} took over 0.41 s after the remote's last output"
    ]
    patches = len(kube.status_patches)
    assert measure(deps, prom, 20) == set()
    run(kube, deps)
    assert len(kube.status_patches) == patches, "nothing new: nothing written"
    assert len(took_over(kube)) == 1

    # its container restarted (the counter starts again at 0) and took over once since
    prom.standby = counters(robot, 1, created=2e9, gap=0.3, at=at + 600)
    assert measure(deps, prom, 30) == {KEY}
    run(kube, deps)
    assert takeovers(kube, robot)[HPE]["count"] == 2
    assert len(took_over(kube)) == 2 and "0.30 s" in took_over(kube)[-1]

    # a new operator (a restart, a failover) reads the count back and reports nothing again
    deps.store.forget(KEY)
    run(kube, deps)
    measure(deps, prom, 40)
    run(kube, deps)
    assert takeovers(kube, robot)[HPE]["count"] == 2 and len(took_over(kube)) == 2


def test_an_active_standby_is_marked_active(kube, deps, prom) -> None:
    robot = with_standbys(kube, deps)
    prom.standby = counters(robot, 0)
    measure(deps, prom, 0)
    prom.active = [(robot, HPE)]
    assert measure(deps, prom, 10) == {KEY}
    run(kube, deps)
    assert takeovers(kube, robot)[HPE]["active"] is True


def test_takeover_events_only_for_robots_listed_before() -> None:
    old = [{"robot": "r1", "takeovers": [{"module": "m", "count": 1}]}, {"robot": "r2"}]
    new = [
        {"robot": "r1", "takeovers": [{"module": "m", "count": 3, "lastGapSeconds": 0.5}]},
        {"robot": "r2", "takeovers": [{"module": "m", "count": 4}]},
    ]
    assert takeover_events(old, new) == [
        (
            "Normal",
            "StandbyTookOver",
            "the standby of m on r1 took over 2 times, the last 0.50 s after the remote's "
            "last output",
        )
    ]
