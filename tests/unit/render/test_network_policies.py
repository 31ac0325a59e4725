"""The fleet's NetworkPolicies allow the flows the plan needs and nothing else (issue 37/9).

Policies add up, so a flow is allowed when any policy selecting the receiver admits it on
ingress and any policy selecting the sender admits it on egress. ``allowed`` evaluates the
rendered objects that way (label selectors, ports), as an enforcing CNI does, and with the
looser reading of kube-router (the bed's enforcer) on top, so a refusal here is a refusal
under both.
"""

from __future__ import annotations

from typing import Any

import pytest

from fogfleet.api.names import MAX_NAME
from fogfleet.render.names import robot_network_policy_name
from fogfleet.render.ros import fleet_network_policies

FLEET = {"fogfleet.io/fleet": "warehouse"}
ROBOTS = ["robot-1", "robot-2"]


def _pod(robot: str, **extra: str) -> dict[str, str]:
    return {
        **FLEET,
        "fogfleet.io/robot": robot,
        "app.kubernetes.io/managed-by": "fogfleet",
        **extra,
    }


A_MODULE = _pod("robot-1", **{"fogfleet.io/module": "planner"})
A_SERVER = _pod("robot-1", **{"app.kubernetes.io/component": "ros-discovery-server"})
B_MODULE = _pod("robot-2", **{"fogfleet.io/module": "planner"})
SHARED = _pod("", **{"fogfleet.io/module": "map-server"})
OTHER_FLEET = {"fogfleet.io/fleet": "yard", "fogfleet.io/robot": "robot-1"}
PROMETHEUS = None  # not a pod: an address outside every selector


def _policies() -> list[dict[str, Any]]:
    return fleet_network_policies(
        fleet="warehouse", namespace="warehouse", selector=FLEET, robots=ROBOTS,
        metrics_ports=[9100], owner_refs=[],
    )  # fmt: skip


def _selects(selector: dict[str, Any], labels: dict[str, str] | None) -> bool:
    return labels is not None and selector["matchLabels"].items() <= labels.items()


def _admits(rules: list[dict[str, Any]], key: str, peer: dict[str, str] | None, port: int) -> bool:
    for rule in rules:
        peers, ports = rule.get(key), rule.get("ports")
        if ports is not None and not any(p["port"] == port for p in ports):
            continue
        if peers is None or any(_selects(p["podSelector"], peer) for p in peers):
            return True
    return False


def allowed(src: dict[str, str] | None, dst: dict[str, str], port: int) -> bool:
    policies = [p["spec"] for p in _policies()]
    on_dst = [p for p in policies if _selects(p["podSelector"], dst)]
    on_src = [p for p in policies if _selects(p["podSelector"], src) and "egress" in p]
    ingress = not on_dst or any(_admits(p["ingress"], "from", src, port) for p in on_dst)
    egress = not on_src or any(_admits(p["egress"], "to", dst, port) for p in on_src)
    # kube-router also runs a sender's packets through the ingress rules of its two-way
    # policies: one admitting (src, dst) with dst selected by that policy lets them out too
    egress = egress or any(
        "Egress" in p["policyTypes"] and _selects(p["podSelector"], dst)
        and _admits(p["ingress"], "from", src, port)
        for p in on_src
    )  # fmt: skip
    return ingress and egress


@pytest.mark.parametrize(
    ("src", "dst"),
    [
        (A_MODULE, A_SERVER),  # a module and its robot's discovery server
        (A_SERVER, A_MODULE),
        (A_MODULE, _pod("robot-1", **{"fogfleet.io/module": "mapper"})),  # same robot
        (A_MODULE, SHARED),  # a robot and the fleet's shared services, both ways
        (SHARED, B_MODULE),
        (SHARED, A_SERVER),
    ],
)
def test_the_planned_flows_are_allowed(src: dict[str, str], dst: dict[str, str]) -> None:
    assert allowed(src, dst, 7400)


@pytest.mark.parametrize(
    ("src", "dst"),
    [
        (A_MODULE, B_MODULE),  # another robot's module, even knowing its address
        (B_MODULE, A_SERVER),  # another robot's discovery server
        (OTHER_FLEET, A_MODULE),  # a pod of another fleet, with the same robot name
        (PROMETHEUS, A_MODULE),  # anything outside the fleet, on a port that is not metrics
    ],
)
def test_a_pod_of_another_robot_is_refused(src: dict[str, str] | None, dst: dict[str, str]) -> None:
    assert not allowed(src, dst, 7400)


def test_metrics_ports_are_open_to_prometheus_but_not_to_another_robots_pods() -> None:
    assert allowed(PROMETHEUS, A_MODULE, 9100)
    assert allowed(PROMETHEUS, SHARED, 9100)
    # ingress is open on 9100, yet robot-1's pods may not send out to robot-2's
    assert not allowed(A_MODULE, B_MODULE, 9100)


def test_every_policy_but_the_metrics_one_closes_both_directions_and_is_labelled() -> None:
    for policy in _policies():
        name = policy["metadata"]["name"]
        # an "any source" rule in a two-way policy would open robot-1's egress to robot-2's
        # metrics port under kube-router, which runs outgoing packets through it too
        want = ["Ingress"] if name == "warehouse-metrics" else ["Ingress", "Egress"]
        assert policy["spec"]["policyTypes"] == want, name
        open_to_all = [r for r in policy["spec"]["ingress"] if "from" not in r]
        assert not open_to_all or want == ["Ingress"], name
        assert policy["metadata"]["labels"] == FLEET


def test_one_policy_per_robot_with_names_that_fit() -> None:
    names = [p["metadata"]["name"] for p in _policies()]
    assert names == ["warehouse-pods", "warehouse-shared", "warehouse-metrics",
                     "warehouse-robot-1-net", "warehouse-robot-2-net"]  # fmt: skip
    long = robot_network_policy_name("f" * 60, "r" * 60)
    assert len(long) <= MAX_NAME
    assert long != robot_network_policy_name("f" * 60, "r" * 59 + "s")
