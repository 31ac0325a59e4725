"""The relays that carry a plan's cut edges across the WAN (issue 47, item 4;
docs/multicluster.md "What crosses the WAN").

An edge of the module graph is cut when an instance runs in a managed cluster and its robot
at the site: the topics the instance subscribes to go out from the robot, those it publishes
come back. Only those cross, and only for the robots concerned (the allow-list is the plan):

* **at the site**, one relay per robot with an instance in a cluster (``site_relays``), on the
  robot's node beside its discovery server, in the robot's discovery network, a client of the
  site's Zenoh router. Its routes (``site_routes``): each topic a cloud instance of the robot
  subscribes to, out; each it publishes, in (a remote instance with an on-board standby
  publishes under ``contract.relay.remote_topic``, which the standby relays on the robot). A
  topic that a cloud instance publishes is routed in, never out as well, so nothing the relay
  brings in goes back out. A shared instance in a cluster concerns every robot of the fleet.
* **in the cluster**, a relay sidecar in the instance's pod (``with_relay``), a client of
  the cluster's Zenoh router (its ClusterClaim ``relay-router.fogfleet.io``). The module and
  its relay are the pod's whole ROS 2 graph (discovery on localhost: the site's discovery
  servers are out of reach there). Its routes (``cloud_routes``) mirror the site's.

The relay runs from the fleet's workload image (``ros.discoveryServerImage``, which also runs
the discovery servers): a user's own module image needs nothing of fogfleet's. Pure: objects
from the rendered Deployments, which carry the module's topics and robot in their environment.
"""

from __future__ import annotations

import copy
import ipaddress
import json
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from fogfleet.api.labels import LABEL_COMPONENT, LABEL_ROBOT, ROLE_REMOTE
from fogfleet.api.names import label_value
from fogfleet.contract.env import (
    ENV_FLEET,
    ENV_LOG_INTERVAL,
    ENV_METRICS_PORT,
    ENV_MODULE_SPEC,
    ENV_ROBOT,
    ENV_ROLE,
)
from fogfleet.contract.relay import (
    ANY_ROBOT,
    ENV_RELAY_ROUTER,
    ENV_RELAY_ROUTES,
    IN,
    OUT,
    RELAY_METRICS_PORT,
    Route,
    key_of,
    remote_topic,
    routes_json,
)
from fogfleet.render.names import relay_name, relay_network_policy_name
from fogfleet.render.ros import RosWiring, on_the_robot, pod_security, ros_env

__all__ = [
    "COMPONENT_RELAY",
    "RELAY_CONTAINER",
    "cloud_routes",
    "relay_network_policy",
    "site_relays",
    "site_routes",
    "with_relay",
]

Obj = dict[str, Any]
COMPONENT_RELAY = "ros-relay"
RELAY_CONTAINER = "fogfleet-relay"
RESOURCES = {
    "requests": {"cpu": "20m", "memory": "96Mi"},
    "limits": {"cpu": "200m", "memory": "192Mi"},
}
LOG_EVERY_SECONDS = "60"  # the relay's counts in its log, once a minute
RELAY_PORT_NAME = "relay-metrics"


def _topic(name: str) -> str:
    return "/" + name.strip("/")


def _env(deployment: Mapping[str, Any]) -> dict[str, str]:
    """The plain values of the module container's environment (what fogfleet rendered)."""
    containers = deployment["spec"]["template"]["spec"]["containers"]
    return {e["name"]: str(e["value"]) for e in containers[0].get("env") or () if "value" in e}


def _instance(deployment: Mapping[str, Any]) -> tuple[str, str, list[str], list[str]] | None:
    """(fleet, robot, the topics it subscribes to, those it publishes as named in its graph)
    of a module's Deployment (None: not one of fogfleet's modules)."""
    env = _env(deployment)
    if ENV_MODULE_SPEC not in env:
        return None
    topics = json.loads(env[ENV_MODULE_SPEC]).get("topics") or {}
    ins = [_topic(t["name"]) for t in topics.get("subscribes") or ()]
    outs = [_topic(t["name"]) for t in topics.get("publishes") or ()]
    if env.get(ENV_ROLE) == ROLE_REMOTE:
        outs = [remote_topic(t) for t in outs]
    return env.get(ENV_FLEET, ""), env.get(ENV_ROBOT, ""), ins, outs


def cloud_routes(deployment: Mapping[str, Any], namespace: str) -> list[Route]:
    """The routes of the relay beside an instance in a managed cluster: its inputs in from its
    robot (every robot for a shared instance), its outputs out under its robot's name."""
    found = _instance(deployment)
    if found is None:
        return []
    fleet, robot, ins, outs = found
    routes = {t: Route(t, key_of(namespace, fleet, robot or ANY_ROBOT, t), IN) for t in ins}
    routes |= {t: Route(t, key_of(namespace, fleet, robot, t), OUT) for t in outs}
    return sorted(routes.values())


def site_routes(
    remote: Iterable[Mapping[str, Any]], robots: Sequence[str], namespace: str
) -> dict[str, list[Route]]:
    """Robot -> the routes of its relay at the site, for the fleet's instances in managed
    clusters (``remote``; ``robots``: the fleet's, whom a shared instance concerns)."""
    by_robot: dict[str, dict[str, Route]] = {}
    for deployment in remote:
        found = _instance(deployment)
        if found is None:
            continue
        fleet, robot, ins, outs = found
        for r in [robot] if robot else robots:
            routes = by_robot.setdefault(r, {})
            for t in outs:  # what the cloud publishes comes in, and so never goes out
                routes[t] = Route(t, key_of(namespace, fleet, robot, t), IN)
            for t in ins:
                if t not in routes:
                    routes[t] = Route(t, key_of(namespace, fleet, r, t), OUT)
    return {r: sorted(routes.values()) for r, routes in sorted(by_robot.items()) if routes}


def _relay_container(image: str, env: Mapping[str, str], routes: list[Route], router: str) -> Obj:
    _, container_sc = pod_security()
    values = {**env, ENV_RELAY_ROUTES: routes_json(routes), ENV_RELAY_ROUTER: router}
    values[ENV_LOG_INTERVAL] = LOG_EVERY_SECONDS
    values[ENV_METRICS_PORT] = str(RELAY_METRICS_PORT)
    # open once every route is declared: ready; alive while it answers
    probe = {"tcpSocket": {"port": RELAY_PORT_NAME}, "periodSeconds": 10}
    return {
        "name": RELAY_CONTAINER,
        "image": image,
        "args": ["relay"],
        "env": [{"name": k, "value": v} for k, v in values.items()],
        "ports": [
            {"name": RELAY_PORT_NAME, "containerPort": RELAY_METRICS_PORT, "protocol": "TCP"}
        ],
        "livenessProbe": dict(probe),
        "readinessProbe": {**probe, "periodSeconds": 5},
        "resources": copy.deepcopy(RESOURCES),
        "securityContext": container_sc,
        "volumeMounts": [{"name": "tmp", "mountPath": "/tmp"}],
    }


def site_relays(
    remote: Iterable[Mapping[str, Any]],
    wiring: RosWiring,
    robot_nodes: Mapping[str, str],
    router: str,
    meta: Mapping[str, Any],
) -> list[Obj]:
    """Each robot's relay Deployment at the site (``robot_nodes``: robot -> its Kubernetes
    node; ``meta``: the fleet's name, namespace, labels and owner references, as its discovery
    servers have them). None without a router to dial (``router``: "")."""
    if not router or not wiring.settings.enabled:
        return []
    fleet, namespace = str(meta["fleet"]), str(meta["namespace"])
    out = []
    for robot, routes in site_routes(remote, sorted(robot_nodes), namespace).items():
        selector = {
            **meta["labels"],
            LABEL_COMPONENT: COMPONENT_RELAY,
            LABEL_ROBOT: label_value(robot),
        }
        obj_meta: Obj = {"name": relay_name(fleet, robot), "namespace": namespace}
        obj_meta["labels"] = dict(selector)
        if meta.get("ownerReferences"):
            obj_meta["ownerReferences"] = [dict(o) for o in meta["ownerReferences"]]
        image = wiring.settings.discovery_server_image
        container = _relay_container(image, ros_env(wiring, robot), routes, router)
        out.append(on_the_robot(obj_meta, selector, robot_nodes[robot], container))
    return out


def _endpoint(router: str) -> tuple[str, int]:
    """(host, port) of a Zenoh endpoint ``proto/HOST:PORT`` (an IPv6 host in brackets)."""
    host, _, port = router.split("/", 1)[-1].rpartition(":")
    return host.strip("[]"), int(port)


def relay_network_policy(router: str, meta: Mapping[str, Any]) -> Obj:
    """The NetworkPolicy that lets the fleet's relays at the site dial ``router`` (the fleet's
    own policies, ``render.ros.fleet_network_policies``, let its pods reach only each other):
    TCP to the router's address and port; a router named by DNS, to its port anywhere and to
    the cluster's DNS."""
    host, port = _endpoint(router)
    to: Obj = {"ports": [{"protocol": "TCP", "port": port}]}
    egress = [to]
    try:
        address = ipaddress.ip_address(host)
    except ValueError:  # a name: resolved by the cluster's DNS, wherever it points
        egress.append({"ports": [{"protocol": p, "port": 53} for p in ("UDP", "TCP")]})
    else:
        to["to"] = [{"ipBlock": {"cidr": f"{address}/{address.max_prefixlen}"}}]
    labels = dict(meta["labels"])
    obj_meta: Obj = {
        "name": relay_network_policy_name(str(meta["fleet"])),
        "namespace": str(meta["namespace"]),
        "labels": labels,
    }
    if meta.get("ownerReferences"):
        obj_meta["ownerReferences"] = [dict(o) for o in meta["ownerReferences"]]
    return {
        "apiVersion": "networking.k8s.io/v1",
        "kind": "NetworkPolicy",
        "metadata": obj_meta,
        "spec": {
            "podSelector": {"matchLabels": {**labels, LABEL_COMPONENT: COMPONENT_RELAY}},
            "policyTypes": ["Egress"],
            "egress": egress,
        },
    }


def with_relay(deployment: Mapping[str, Any], router: str | None, image: str) -> Obj:
    """An instance bound for a managed cluster, as the cluster gets it: its ROS 2 graph kept
    in its pod (discovery on localhost; no discovery server of the site) and, given the
    cluster's router, a relay sidecar carrying its routes."""
    out = copy.deepcopy(dict(deployment))
    pod = out["spec"]["template"]["spec"]
    env = _env(deployment)
    ros = {k: v for k, v in env.items() if k.startswith(("ROS_", "RMW_", "FASTDDS_"))}
    if not ros:  # the fleet wires ROS itself
        return out
    ros.pop("ROS_DISCOVERY_SERVER", None)
    ros["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    for container in pod["containers"]:
        container["env"] = [
            {**e, "value": ros[e["name"]]} if e["name"] in ros else e
            for e in container.get("env") or ()
            if e["name"] != "ROS_DISCOVERY_SERVER"
        ]
    namespace = str(out["metadata"]["namespace"])
    routes = cloud_routes(deployment, namespace)
    if router and routes:
        pod["containers"].append(_relay_container(image, ros, routes, router))
    return out
