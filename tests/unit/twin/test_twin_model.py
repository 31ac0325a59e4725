"""The twin's pure parts: scenario, queue simulation, pods -> replicas."""

from __future__ import annotations

import math
from typing import Any

import pytest

from fogfleet.autoscaling.policy import Pool
from fogfleet.errors import InvalidSpec
from fogfleet.twin.model import Rejected, Served, ServiceSim
from fogfleet.twin.pods import count_replicas, ready_since
from fogfleet.twin.scenario import parse_scenario

MU = math.log(10) / 0.35
EDGE = Pool("edge", 1, 17, MU, 0.35, 0.99, setup_seconds=1.8, accepts_private=True)
CLOUD = Pool("cloud", 1, 19, MU, 0.5, 0.99, setup_seconds=4.7, network_delay_seconds=0.0155)


def sim(edge: int, cloud: int, seed: int = 1) -> ServiceSim:
    s = ServiceSim([EDGE, CLOUD], seed=seed, reserve=2)
    s.set_replicas("edge", edge)
    s.set_replicas("cloud", cloud)
    return s


def served(records: list[Any], **match: Any) -> list[Served]:
    return [r for r in records if isinstance(r, Served)
            and all(getattr(r, k) == v for k, v in match.items())]  # fmt: skip


def rejected(records: list[Any], **match: Any) -> list[Rejected]:
    return [r for r in records if isinstance(r, Rejected)
            and all(getattr(r, k) == v for k, v in match.items())]  # fmt: skip


# --------------------------------------------------------------------------- scenario


def test_scenario_rate_is_piecewise_constant_from_each_phase() -> None:
    sc = parse_scenario(
        {
            "services": [
                {
                    "module": "det",
                    "privateShare": 0.3,
                    "phases": [
                        {"atSeconds": 60, "requestsPerSecond": 90},
                        {"atSeconds": 0, "requestsPerSecond": 20},
                    ],
                }
            ]
        },
        default_namespace="fleet",
    )
    svc = sc.service("fleet", "det")
    assert svc is not None
    assert (svc.rate_at(0), svc.rate_at(59.9), svc.rate_at(60), svc.rate_at(1e6)) == (
        20,
        20,
        90,
        90,
    )


@pytest.mark.parametrize(
    ("doc", "field"),
    [
        ({}, "services"),
        ({"services": [{"phases": []}]}, "services[0].module"),
        ({"services": [{"module": "d", "phases": []}]}, "services[0].phases"),
        ({"services": [{"module": "d", "privateShare": 2,
                        "phases": [{"requestsPerSecond": 1}]}]}, "services[0].privateShare"),
        ({"services": [{"module": "d", "phases": [{"requestsPerSecond": "many"}]}]},
         "services[0].phases[0].requestsPerSecond"),
        ({"services": [{"module": "d", "rate": 1, "phases": [{"requestsPerSecond": 1}]}]},
         "services[0].rate"),
    ],
)  # fmt: skip
def test_bad_scenarios_name_the_field(doc: Any, field: str) -> None:
    with pytest.raises(InvalidSpec) as info:
        parse_scenario(doc, where="s.yaml")
    assert info.value.field == field


# --------------------------------------------------------------------------- queue


def test_no_replicas_rejects_everything_for_lack_of_capacity() -> None:
    out = sim(0, 0).advance(10.0, 5.0, 5.0)
    assert out and all(isinstance(r, Rejected) and r.reason == "capacity" for r in out)


def test_private_requests_are_never_served_in_the_cloud() -> None:
    out = sim(1, 10).advance(60.0, 20.0, 20.0)
    assert served(out, tier="cloud") and not served(out, tier="cloud", private=True)
    assert rejected(out, private=True)  # one edge replica cannot carry 20 private req/s


def test_light_load_is_served_at_the_service_time_plus_round_trip() -> None:
    out = sim(5, 1).advance(200.0, 2.0, 4.0)
    assert not rejected(out)
    edge = served(out, tier="edge")
    mean = sum(r.response_seconds for r in edge) / len(edge)
    assert mean == pytest.approx(1 / MU, rel=0.15)
    assert len(out) == pytest.approx(6 * 200, rel=0.1)


def test_overload_rejects_on_the_slo_and_more_replicas_fix_it() -> None:
    small = sim(2, 1).advance(120.0, 15.0, 45.0)
    big = sim(17, 19).advance(120.0, 15.0, 45.0)
    assert len(rejected(small, reason="slo")) > 0.3 * len(small)
    assert len(rejected(big)) < 0.02 * len(big)


def test_removed_replicas_finish_their_requests_and_take_no_more() -> None:
    s = sim(10, 0)
    s.advance(5.0, 0.0, 60.0)
    s.set_replicas("edge", 1)
    s.advance(5.001, 0.0, 0.0)
    busy = len(s.pools[0].busy)
    out = s.advance(30.0, 0.0, 0.0)
    assert busy <= 10 and len(s.pools[0].busy) == 0 and s.queue_length("edge") == 0
    assert all(isinstance(r, Served) for r in out)


def test_small_steps_match_one_big_step_statistically_and_runs_are_seeded() -> None:
    a, b = sim(4, 2, seed=3), sim(4, 2, seed=3)
    one = a.advance(300.0, 6.0, 14.0)
    many: list[Any] = []
    for k in range(1, 1501):
        many += b.advance(k * 0.2, 6.0, 14.0)
    assert len(many) == pytest.approx(len(one), rel=0.08)
    assert sim(4, 2, seed=9).advance(50.0, 6.0, 14.0) == sim(4, 2, seed=9).advance(50.0, 6.0, 14.0)


# --------------------------------------------------------------------------- pods


def pod(
    name: str,
    *,
    tier: str | None = None,
    node: str = "edge-1",
    ready_at: str = "2026-01-01T00:00:00Z",
    phase: str = "Running",
    ready: str = "True",
    deleting: bool = False,
    module: str = "det",
) -> dict[str, Any]:
    labels = {"fogfleet.io/module": module, "app.kubernetes.io/managed-by": "fogfleet"}
    if tier:
        labels["fogfleet.io/tier"] = tier
    meta: dict[str, Any] = {"name": name, "namespace": "fleet", "labels": labels}
    if deleting:
        meta["deletionTimestamp"] = "2026-01-01T00:00:00Z"
    return {
        "metadata": meta,
        "spec": {"nodeName": node},
        "status": {"phase": phase, "conditions": [
            {"type": "Ready", "status": ready, "lastTransitionTime": ready_at}]},
    }  # fmt: skip


def test_pods_count_per_tier_starting_until_setup_has_passed() -> None:
    t0 = ready_since(pod("x"))
    assert t0 is not None
    pods = [
        pod("a", tier="edge"),
        pod("b", node="edge-2"),  # no tier label: the node's
        pod("c", node="cloud-1"),
        pod("d", tier="edge", ready_at="2026-01-01T00:00:01Z"),  # just became ready
        pod("e", tier="edge", phase="Pending"),
        pod("f", tier="edge", ready="False"),
        pod("g", tier="edge", deleting=True),
    ]
    nodes = {"edge-1": "edge", "edge-2": "edge", "cloud-1": "cloud"}
    setup = {("fleet", "det", "edge"): 1.8, ("fleet", "det", "cloud"): 4.7}
    counts = count_replicas(pods, nodes, setup, t0 + 2.0)
    assert counts == {("fleet", "det"): {"edge": (2, 1), "cloud": (0, 1)}}
