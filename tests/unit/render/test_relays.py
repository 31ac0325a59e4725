"""The relays of a plan's cut edges (render.relays; issue 47, item 4): what crosses the WAN is
the topics of the instances in managed clusters, for their robots, each way once."""

from __future__ import annotations

import json
from typing import Any

import pytest

from fogfleet.api.labels import LABEL_COMPONENT, LABEL_FLEET, LABEL_ROBOT
from fogfleet.api.v1alpha1.robotfleet import RosSettings
from fogfleet.contract.relay import (
    ENV_RELAY_ROUTER,
    ENV_RELAY_ROUTES,
    IN,
    OUT,
    RELAY_METRICS_PORT,
    Route,
    routes_from_json,
)
from fogfleet.render.relays import (
    COMPONENT_RELAY,
    RELAY_CONTAINER,
    cloud_routes,
    relay_network_policy,
    site_relays,
    site_routes,
    with_relay,
)
from fogfleet.render.ros import RosWiring

Obj = dict[str, Any]
NS = "warehouse"
ROUTER = "tcp/198.18.0.1:7447"
WIRING = RosWiring(RosSettings(), {"robot-1": "10.0.0.1:11811", "robot-2": "10.0.0.2:11811"})


def _deployment(robot: str, subscribes: list[str], publishes: list[str], role: str = "") -> Obj:
    spec = {
        "topics": {
            "subscribes": [{"name": t, "sizeBytes": 100, "rateHz": 10} for t in subscribes],
            "publishes": [{"name": t, "sizeBytes": 100, "rateHz": 10} for t in publishes],
        }
    }
    env = {
        "FOGFLEET_FLEET": "fleet",
        "FOGFLEET_ROBOT": robot,
        "FOGFLEET_MODULE_SPEC": json.dumps(spec),
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "ROS_DOMAIN_ID": "0",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
        "ROS_DISCOVERY_SERVER": WIRING.server_for(robot),
    }
    if role:
        env["FOGFLEET_ROLE"] = role
    pairs = [{"name": k, "value": v} for k, v in env.items()]
    containers = [{"name": "mapper", "image": "user/mapper", "env": pairs}]
    containers.append({"name": "sidecar", "image": "user/sidecar", "env": list(pairs)})
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {"name": f"fleet-{robot or 'shared'}-mapper", "namespace": NS},
        "spec": {"template": {"spec": {"containers": containers}}},
    }


def _key(robot: str, topic: str) -> str:
    return f"fogfleet/{NS}/fleet/{robot}/{topic}"


def test_an_instance_in_the_cloud_takes_its_robots_inputs_and_sends_its_outputs_back() -> None:
    mapper = _deployment("robot-1", ["scan", "/odom"], ["map"])
    assert cloud_routes(mapper, NS) == sorted([
        Route("/scan", _key("robot-1", "scan"), IN),
        Route("/odom", _key("robot-1", "odom"), IN),
        Route("/map", _key("robot-1", "map"), OUT),
    ])  # fmt: skip
    assert site_routes([mapper], ["robot-1", "robot-2"], NS) == {
        "robot-1": sorted(
            [
                Route("/scan", _key("robot-1", "scan"), OUT),
                Route("/odom", _key("robot-1", "odom"), OUT),
                Route("/map", _key("robot-1", "map"), IN),
            ]
        )
    }, "robot-2 has nothing in the cloud: nothing of it crosses"


def test_a_shared_instance_hears_every_robot_and_answers_every_robot() -> None:
    planner = _deployment("", ["goal"], ["plan"])
    assert cloud_routes(planner, NS) == [
        Route("/goal", _key("*", "goal"), IN),
        Route("/plan", _key("_shared", "plan"), OUT),
    ]
    routes = site_routes([planner], ["robot-1", "robot-2"], NS)
    assert routes == {
        r: [Route("/goal", _key(r, "goal"), OUT), Route("/plan", _key("_shared", "plan"), IN)]
        for r in ("robot-1", "robot-2")
    }


def test_a_remote_instance_with_a_standby_answers_under_remote() -> None:
    detector = _deployment("robot-1", ["scan"], ["objects"], role="remote")
    assert Route("/objects/remote", _key("robot-1", "objects/remote"), OUT) in cloud_routes(
        detector, NS
    )
    site = site_routes([detector], ["robot-1"], NS)["robot-1"]
    assert Route("/objects/remote", _key("robot-1", "objects/remote"), IN) in site


def test_a_topic_the_cloud_publishes_comes_in_and_never_goes_back_out() -> None:
    """One cloud instance publishes /plan, another subscribes to it: the site's relay brings
    /plan in only (the subscriber hears the publisher through the cloud's router)."""
    planner = _deployment("robot-1", ["goal"], ["plan"])
    follower = _deployment("robot-1", ["plan"], ["cmd"])
    for remote in ([follower, planner], [planner, follower]):
        routes = site_routes(remote, ["robot-1"], NS)["robot-1"]
        plan = [r for r in routes if r.topic == "/plan"]
        assert plan == [Route("/plan", _key("robot-1", "plan"), IN)]
        assert len({r.topic for r in routes}) == len(routes)


def _env(container: Obj) -> dict[str, str]:
    return {e["name"]: e["value"] for e in container["env"]}


def test_the_cloud_gets_its_instance_with_a_relay_and_its_graph_in_the_pod() -> None:
    mapper = _deployment("robot-1", ["scan"], ["map"])
    sent = with_relay(mapper, ROUTER, "fogfleet/ros2-module:1")
    *own, relay = sent["spec"]["template"]["spec"]["containers"]
    assert [c["name"] for c in own] == ["mapper", "sidecar"]
    for container in own:
        env = _env(container)
        assert "ROS_DISCOVERY_SERVER" not in env, "the site's discovery server is out of reach"
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert relay["name"] == RELAY_CONTAINER and relay["image"] == "fogfleet/ros2-module:1"
    env = _env(relay)
    assert env[ENV_RELAY_ROUTER] == ROUTER and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert routes_from_json(env[ENV_RELAY_ROUTES]) == cloud_routes(mapper, NS)
    assert relay["securityContext"]["readOnlyRootFilesystem"] is True
    assert mapper["spec"]["template"]["spec"]["containers"][0]["env"][-1]["name"] == (
        "ROS_DISCOVERY_SERVER"
    ), "the site's object is left as it was"


def test_without_a_router_or_topics_the_cloud_instance_gets_no_relay() -> None:
    no_router = with_relay(_deployment("robot-1", ["scan"], []), None, "img")
    no_topics = with_relay(_deployment("robot-1", [], []), ROUTER, "img")
    for sent in (no_router, no_topics):
        containers = sent["spec"]["template"]["spec"]["containers"]
        assert [c["name"] for c in containers] == ["mapper", "sidecar"]
        assert _env(containers[0])["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


META = {"fleet": "fleet", "namespace": NS, "labels": {LABEL_FLEET: "fleet"}}


def test_each_robot_with_an_instance_in_the_cloud_gets_a_relay_on_its_own_node() -> None:
    far = [_deployment("robot-1", ["scan"], ["map"])]
    nodes = {"robot-1": "pi-1", "robot-2": "pi-2"}
    (relay,) = site_relays(far, WIRING, nodes, ROUTER, META)
    assert relay["metadata"]["name"] == "fleet-robot-1-relay"
    labels = relay["spec"]["template"]["metadata"]["labels"]
    assert labels[LABEL_COMPONENT] == COMPONENT_RELAY and labels[LABEL_ROBOT] == "robot-1"
    pod = relay["spec"]["template"]["spec"]
    terms = pod["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"]
    assert terms["nodeSelectorTerms"][0]["matchExpressions"][0]["values"] == ["pi-1"]
    env = _env(pod["containers"][0])
    assert env["ROS_DISCOVERY_SERVER"] == "10.0.0.1:11811", "in its robot's discovery network"
    assert env[ENV_RELAY_ROUTER] == ROUTER
    assert pod["containers"][0]["args"] == ["relay"]
    # probed on its metrics port, which it opens once its routes are declared
    (port,) = pod["containers"][0]["ports"]
    assert port["containerPort"] == RELAY_METRICS_PORT == int(env["FOGFLEET_METRICS_PORT"])
    for probe in ("livenessProbe", "readinessProbe"):
        assert pod["containers"][0][probe]["tcpSocket"]["port"] == port["name"]


@pytest.mark.parametrize(
    ("router", "ros"), [("", RosSettings()), (ROUTER, RosSettings(enabled=False))]
)
def test_no_site_relay_without_a_router_or_with_the_wiring_off(router: str, ros: Any) -> None:
    far = [_deployment("robot-1", ["scan"], ["map"])]
    wiring = RosWiring(ros, WIRING.servers)
    assert site_relays(far, wiring, {"robot-1": "pi-1"}, router, META) == []


def test_the_relays_may_dial_the_router_and_nothing_else_new() -> None:
    policy = relay_network_policy(ROUTER, META)
    assert policy["metadata"]["name"] == "fleet-relay"
    spec = policy["spec"]
    assert spec["podSelector"]["matchLabels"][LABEL_COMPONENT] == COMPONENT_RELAY
    assert spec["policyTypes"] == ["Egress"]
    assert spec["egress"] == [
        {
            "ports": [{"protocol": "TCP", "port": 7447}],
            "to": [{"ipBlock": {"cidr": "198.18.0.1/32"}}],
        }
    ]
    named = relay_network_policy("tcp/zenoh.fogfleet-system:7447", META)["spec"]["egress"]
    assert named[0] == {"ports": [{"protocol": "TCP", "port": 7447}]}
    assert {p["port"] for p in named[1]["ports"]} == {53}, "the router's name is resolved"
    v6 = relay_network_policy("tcp/[fd00::1]:7447", META)["spec"]["egress"][0]
    assert v6["to"] == [{"ipBlock": {"cidr": "fd00::1/128"}}]
