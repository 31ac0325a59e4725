"""Every object a fleet renders has a name of its own across all fleets of a namespace, valid
for its kind (issue 45 item 4).

The property test cuts fleet, robot and module names out of one text at different places, so
they join alike (fleet ``a-b`` robot ``c`` and fleet ``a`` robot ``b-c``), with dots, names
that begin with a digit and names of 63 characters and more; it renders what each fleet of
the namespace gets (the robots' discovery Services and Deployments, the NetworkPolicies, the
module Deployments with their replicas and standbys, HPAs and ScaledObjects) and checks that
no two of a kind share a name and that each name is one its kind takes.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from itertools import combinations

from hypothesis import given, settings
from hypothesis import strategies as st

from fogfleet.api.labels import LABEL_FLEET, ROLE_STANDBY
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.robotfleet import RosSettings
from fogfleet.api.v1alpha1.scaling import ScalingSpec
from fogfleet.domain.problem import Instance
from fogfleet.render.names import (
    deployment_name,
    discovery_service_name,
    pod_deployment,
    relay_name,
    relay_network_policy_name,
    robot_network_policy_name,
)
from fogfleet.render.ros import fleet_network_policies, render_discovery
from fogfleet.render.scaling import render_hpa, render_scaled_object

DNS_1035 = re.compile(r"[a-z]([-a-z0-9]*[a-z0-9])?")
DNS_1123_LABEL = re.compile(r"[a-z0-9]([-a-z0-9]*[a-z0-9])?")
LABEL_VALUE = re.compile(r"(([A-Za-z0-9][-A-Za-z0-9_.]*)?[A-Za-z0-9])?")
# Kubernetes names a Deployment's pod <deployment>-<pod-template-hash, up to 10>-<5 random>,
# cutting what comes before the random part to 58 characters (SimpleNameGenerator)
POD_BASE = 58
SCALING = ScalingSpec.model_validate({"minReplicas": 1, "maxReplicas": 3})


def valid_service(name: str) -> bool:
    """A Service name: a DNS-1035 label."""
    return len(name) <= 63 and DNS_1035.fullmatch(name) is not None


def valid_deployment(name: str) -> bool:
    """A DNS-1123 label that, with a dash, begins its pods' names."""
    return len(name) < POD_BASE and DNS_1123_LABEL.fullmatch(name) is not None


def valid_label_name(name: str) -> bool:
    """A DNS-1123 label, so also a label value (NetworkPolicy, HPA, ScaledObject)."""
    return len(name) <= 63 and DNS_1123_LABEL.fullmatch(name) is not None


# ------------------------------------------------------------------------------ the strategy
# a plain alphabet, not st.from_regex: that builds a Unicode character map on first use (seconds
# of CPU on a fresh clone with no .hypothesis cache, over the unit tier's limit)
_short = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789", min_size=1, max_size=5)
_long = st.builds(
    lambda lead, n: lead + "x" * (n - 1), st.sampled_from("a9"), st.sampled_from([57, 62, 63, 64])
)
_token = st.one_of(_short, _short, _short, _long)


@st.composite
def alike(draw: st.DrawFn) -> list[tuple[str, str, str]]:
    """(fleet, robot, module) triples cut from one text of tokens at different places."""
    tokens = draw(st.lists(_token, min_size=4, max_size=6))
    seps = draw(st.lists(st.sampled_from("--."), min_size=len(tokens), max_size=len(tokens)))

    def join(lo: int, hi: int) -> str:
        return "".join(t + s for t, s in zip(tokens[lo:hi], seps[lo:hi], strict=True))[:-1]

    cuts = list(combinations(range(1, len(tokens)), 2))
    chosen = draw(st.lists(st.sampled_from(cuts), min_size=2, max_size=6, unique=True))
    out = [(join(0, i), join(i, j), join(j, len(tokens))) for i, j in chosen]
    return [t for t in out if all(len(p) <= 253 for p in t)]


class Names:
    """Name -> what it names, per kind: a second thing under one name is a collision."""

    def __init__(self) -> None:
        self.by_kind: dict[str, dict[str, object]] = {}

    def add(self, kind: str, name: str, what: object, valid: Callable[[str], bool]) -> None:
        assert valid(name), f"{kind} {name!r} ({what}) is not a valid name"
        have = self.by_kind.setdefault(kind, {}).setdefault(name, what)
        assert have == what, f"{kind} {name} names both {have} and {what}"


def render_names(triples: list[tuple[str, str, str]]) -> Names:
    """Render every fleet of ``triples`` into one namespace and collect the names."""
    fleets: dict[str, tuple[set[str], set[str]]] = {}
    for fleet, robot, module in triples:
        robots, modules = fleets.setdefault(fleet, (set(), set()))
        robots.add(robot)
        modules.add(module)
    names = Names()
    for fleet, (robots, modules) in sorted(fleets.items()):
        labels = {LABEL_FLEET: label_value(fleet)}
        for robot in sorted(robots):
            service, server = render_discovery(
                fleet=fleet, namespace="ns", robot=robot, node_name=robot,
                settings=RosSettings(), labels=labels, owner_refs=[],
            )  # fmt: skip
            names.add("Service", service["metadata"]["name"], (fleet, robot), valid_service)
            server_name = server["metadata"]["name"]
            names.add("Deployment", server_name, ("dds", fleet, robot), valid_deployment)
            relay = relay_name(fleet, robot)
            names.add("Deployment", relay, ("relay", fleet, robot), valid_deployment)
            assert all(LABEL_VALUE.fullmatch(v) for v in service["spec"]["selector"].values())
        for policy in fleet_network_policies(
            fleet=fleet, namespace="ns", selector=labels, robots=sorted(robots),
            metrics_ports=[9100], owner_refs=[],
        ):  # fmt: skip
            what = (fleet, json.dumps(policy["spec"], sort_keys=True))
            names.add("NetworkPolicy", policy["metadata"]["name"], what, valid_label_name)
        relays = relay_network_policy_name(fleet)
        names.add("NetworkPolicy", relays, (fleet, "relay"), valid_label_name)
        instances = [Instance(r, m, 0) for r in robots for m in modules]
        instances += [Instance("", m, k) for m in modules for k in (0, 1)]
        for inst in instances:
            for role in ("", ROLE_STANDBY):
                name = deployment_name(fleet, inst, role)
                names.add("Deployment", name, (fleet, inst, role), valid_deployment)
        for module in sorted(modules):
            hpa = render_hpa(SCALING, fleet=fleet, module=module, namespace="ns", target="t")
            names.add("HPA", hpa["metadata"]["name"], (fleet, module), valid_label_name)
            scaled = render_scaled_object(
                SCALING, fleet=fleet, module=module, namespace="ns", target="t",
                prometheus_url="http://p",
            )  # fmt: skip
            names.add("ScaledObject", scaled["metadata"]["name"], (fleet, module), valid_label_name)
    return names


# ------------------------------------------------------------------------------------ tests
@settings(max_examples=60, deadline=None)
@given(triples=alike())
def test_fleets_whose_names_join_alike_never_share_an_object(
    triples: list[tuple[str, str, str]],
) -> None:
    render_names(triples)


def test_fleet_a_b_robot_c_and_fleet_a_robot_b_c_have_their_own_discovery_server() -> None:
    names = render_names([("a-b", "c", "m"), ("a", "b-c", "m")])
    assert len(names.by_kind["Service"]) == 2
    assert len([n for n, w in names.by_kind["Deployment"].items() if w[0] == "dds"]) == 2
    # and a NetworkPolicy for each robot: robot isolation stays (4 policies per fleet, and
    # the relays' to the site's router)
    assert len(names.by_kind["NetworkPolicy"]) == 10


def test_a_fleet_whose_name_begins_with_a_digit_gets_services_the_api_server_takes() -> None:
    names = render_names([("42-warehouse", "robot-1", "nav"), ("7", "1", "2")])
    assert all(valid_service(n) for n in names.by_kind["Service"])
    assert re.fullmatch(r"dds-7-1-[0-9a-f]{8}", discovery_service_name("7", "1"))


def test_a_join_that_could_be_read_two_ways_keeps_its_readable_head_and_adds_a_hash() -> None:
    name = discovery_service_name("warehouse-lite", "robot-1")
    assert re.fullmatch(r"warehouse-lite-robot-1-dds-[0-9a-f]{8}", name), name
    name = robot_network_policy_name("warehouse-lite", "robot-1")
    assert re.fullmatch(r"warehouse-lite-robot-1-net-[0-9a-f]{8}", name), name


def test_names_that_cannot_be_read_two_ways_stay_as_they_were() -> None:
    names = render_names([("warehouse", "robot-1", "object-detector")])
    assert set(names.by_kind["Service"]) == {"warehouse-robot-1-dds"}
    assert set(names.by_kind["NetworkPolicy"]) == {
        "warehouse-pods", "warehouse-shared", "warehouse-metrics", "warehouse-robot-1-net",
        "warehouse-relay",
    }  # fmt: skip
    assert set(names.by_kind["HPA"]) == {"warehouse-object-detector-hpa"}
    assert set(names.by_kind["ScaledObject"]) == {"warehouse-object-detector-scaler"}
    # a fleet-wide policy has one name in it: a dash there is never ambiguous
    assert (
        "warehouse-lite-pods"
        in render_names([("warehouse-lite", "r", "m")]).by_kind["NetworkPolicy"]
    )


def _pod_of(deployment: str) -> str:
    """The name Kubernetes gives a pod of ``deployment`` (longest pod-template-hash)."""
    replica_set = f"{deployment}-bcdfghjklm"
    return f"{replica_set}-"[:POD_BASE] + "x2x4z"


@settings(max_examples=40, deadline=None)
@given(triples=alike())
def test_a_pod_is_known_by_its_deployments_name(triples: list[tuple[str, str, str]]) -> None:
    """Among the Deployments of every fleet of the namespace (the drift pass tells a fleet's
    pods from another's in Prometheus this way)."""
    deployments = set(render_names(triples).by_kind["Deployment"])
    for name in deployments:
        assert pod_deployment(_pod_of(name), deployments) == name
    yard = "yard-robot-1-nav-0c1f2d3e-7d9f8c6b5-x2x4z"
    assert pod_deployment(yard, {"warehouse-robot-1-nav-0c1f2d3e"}) is None
