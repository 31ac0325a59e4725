"""The portable part of the suite: what any cluster labelled as docs/development.md says must
show, through a plain kubeconfig, kubectl and helm only (``make e2e KUBECONFIG=...``; on the
bed it runs in ``make e2e`` too, through the bed's kubeconfig and nothing else of the bed).

The operator is installed in-cluster by its chart; a small ROS 2 fleet sized to the labelled
nodes (``e2e/portable/fleet.py``) gets Ready; its pods run where the plan says; messages cross
nodes within each robot and never between robots; and the offloaded detector's on-board
standby takes over when the remote instance goes away (its pod deleted: no link emulation) and
hands back once the replacement answers. Every figure comes from the workloads' own counters,
read inside the pods with ``kubectl exec``. The tests run in file order on one fleet.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import all_pods, bound_node, fleet, install_crds, wait_ready
from e2e.portable import chart, nodes
from e2e.portable.fleet import (
    DETECTOR,
    FLEET,
    METRICS_PORT,
    MODULES,
    PLANNER,
    SAFETY,
    SENSOR,
    fleet_objects,
)
from e2e.portable.metrics import Metrics, scrape
from e2e.portable.settings import Settings

pytestmark = [pytest.mark.e2e, pytest.mark.portable, pytest.mark.timeout(900)]

OPERATOR_SELECTOR = (
    f"app.kubernetes.io/instance={chart.RELEASE},app.kubernetes.io/component=operator"
)
STANDBY = "fallback-standby"
Obj = dict[str, Any]


@dataclass(frozen=True)
class Portable:
    namespace: str
    topology: nodes.Topology
    settings: Settings


def _operator_log(kube: Kube) -> tuple[str, str]:
    proc = kube.kubectl("logs", "-n", chart.NAMESPACE, "-l", OPERATOR_SELECTOR, "--tail=150",
                        "--all-containers", check=False)  # fmt: skip
    return "in-cluster operator log", proc.stdout + proc.stderr


@pytest.fixture(scope="module")
def portable(kube: Kube, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Portable]:
    try:
        settings = Settings.from_env()
        topology = nodes.pick(kube.kubectl_json("get", "nodes")["items"])
    except (ValueError, nodes.NotEnoughNodes) as exc:
        pytest.fail(f"the portable suite cannot run on this cluster: {exc}", pytrace=False)
    print(f"portable fleet on robots {topology.robots}, edge/cloud {topology.offload}")
    install_crds(kube)
    helm = chart.Helm(settings.helm, kube.kubeconfig, tmp_path_factory.mktemp("helm-home"))
    helm.uninstall()  # an interrupted earlier run's release
    ns = f"e2e-portable-{secrets.token_hex(3)}"
    kube.apply({"apiVersion": "v1", "kind": "Namespace",
                "metadata": {"name": ns, "labels": {"fogfleet.io/e2e": "true"}}})  # fmt: skip
    declared = nodes.compute_nodes(topology)
    created = [
        c["metadata"]["name"]
        for c in declared
        if kube.kubectl("get", "computenode", c["metadata"]["name"], check=False).returncode != 0
    ]
    try:
        kube.apply(declared)
        helm(*chart.install_args(ns, settings.operator_image, settings.pull_policy,
                                 topology.node_selector))  # fmt: skip
        kube.apply(fleet_objects(topology, ns, settings.module_image, settings.pull_policy))
        yield Portable(ns, topology, settings)
    finally:
        kube.kubectl("delete", "namespace", ns, "--ignore-not-found", "--timeout=180s",
                     check=False, timeout=200)  # fmt: skip
        helm.uninstall()
        kube.kubectl("delete", "namespace", chart.NAMESPACE, "--ignore-not-found",
                     "--wait=false", check=False)  # fmt: skip
        for name in created:
            kube.kubectl("delete", "computenode", name, "--ignore-not-found", check=False)


@pytest.fixture
def ready(kube: Kube, portable: Portable, diagnostics: list[Any]) -> Portable:
    """The portable fleet, Ready (the operator's log is dumped when a test fails)."""
    diagnostics.append(lambda: _operator_log(kube))
    wait_ready(kube, portable.namespace, FLEET, timeout=420)
    return portable


def _ready(pod: Obj) -> bool:
    return any(c["type"] == "Ready" and c["status"] == "True"
               for c in (pod.get("status") or {}).get("conditions") or [])  # fmt: skip


def _module_pods(kube: Kube, ns: str) -> list[Obj]:
    return [
        p
        for p in all_pods(kube, ns)
        if {"fogfleet.io/module", "fogfleet.io/instance"} <= set(p["metadata"].get("labels") or {})
        and not p["metadata"].get("deletionTimestamp")
    ]


def _pod(pods: list[Obj], robot: str, module: str, standby: bool = False) -> Obj:
    for pod in pods:
        labels = pod["metadata"]["labels"]
        if (
            labels.get("fogfleet.io/robot") == robot
            and labels.get("fogfleet.io/module") == module
            and (labels.get("app.kubernetes.io/component") == STANDBY) == standby
        ):
            return pod
    raise AssertionError(f"no {'standby ' if standby else ''}{module} pod of {robot}")


def _metrics(kube: Kube, ns: str, pod: Obj) -> Metrics:
    container = pod["spec"]["containers"][0]["name"]
    return scrape(kube, ns, pod["metadata"]["name"], container, METRICS_PORT)


def _not_yet(check: Callable[[], bool]) -> Callable[[], bool]:
    """``check`` for ``wait_for``, where a pod that does not answer yet (kubectl exec failed,
    or the pod is being replaced) means "not yet", not a failure."""

    def safe() -> bool:
        try:
            return check()
        except AssertionError:
            return False

    return safe


def _placement(kube: Kube, ns: str) -> dict[tuple[str, str], str]:
    status = fleet(kube, ns, FLEET)["status"]
    return {(p["robot"], p["module"]): p["node"] for p in status["placement"]}


def test_the_chart_runs_the_operator_image_in_cluster_off_the_robots(
    kube: Kube, ready: Portable
) -> None:
    (pod,) = [p for p in kube.kubectl_json("get", "pods", "-n", chart.NAMESPACE, "-l",
                                           OPERATOR_SELECTOR)["items"]
              if not p["metadata"].get("deletionTimestamp")]  # fmt: skip
    node = kube.kubectl_json("get", "node", pod["spec"]["nodeName"])
    assert node["metadata"]["labels"].get(nodes.TIER_LABEL) != "robot", pod["spec"]["nodeName"]
    for key, value in ready.topology.node_selector.items():
        assert node["metadata"]["labels"].get(key) == value, (key, pod["spec"]["nodeName"])
    (status,) = pod["status"]["containerStatuses"]
    assert status["image"].endswith(ready.settings.operator_image), status["image"]
    assert status["ready"] is True and _ready(pod)
    # the fleet's status was written by that operator: it names the plan it applied
    assert fleet(kube, ready.namespace, FLEET)["status"]["placement"]


def test_the_fleet_is_ready_and_every_pod_runs_where_it_was_planned(
    kube: Kube, ready: Portable
) -> None:
    ns, topo = ready.namespace, ready.topology
    planned = _placement(kube, ns)
    assert set(planned) == {(r, m) for r in topo.robots for m in MODULES}, sorted(planned)
    for robot in topo.robots:
        assert planned[(robot, SENSOR)] == robot and planned[(robot, SAFETY)] == robot
        assert planned[(robot, PLANNER)] in topo.offload  # required off the robots
    deps = kube.kubectl_json("get", "deployments", "-n", ns)["items"]
    pods = _module_pods(kube, ns)
    checked = 0
    for dep in deps:
        ann = dep["metadata"].get("annotations") or {}
        if "fogfleet.io/module" not in ann:
            continue  # a robot's discovery server
        robot, module = ann["fogfleet.io/robot"], ann["fogfleet.io/module"]
        standby = ann.get("fogfleet.io/role") == "standby"
        want = robot if standby else planned[(robot, module)]
        assert bound_node(dep) == [want], dep["metadata"]["name"]
        pod = _pod(pods, robot, module, standby)
        assert pod["spec"]["nodeName"] == want and _ready(pod), pod["metadata"]["name"]
        checked += 1
    standbys = sum(planned[(r, DETECTOR)] != r for r in topo.robots)
    assert checked == len(planned) + standbys, checked


def test_messages_cross_nodes_within_each_robot_and_never_between_robots(
    kube: Kube, ready: Portable
) -> None:
    ns, topo = ready.namespace, ready.topology
    pods = _module_pods(kube, ns)

    def heard() -> bool:
        for robot in topo.robots:
            planner = _metrics(kube, ns, _pod(pods, robot, PLANNER))
            safety = _metrics(kube, ns, _pod(pods, robot, SAFETY))
            if not (
                planner.total("fogfleet_messages_received_total", topic="scan") > 20
                and safety.total("fogfleet_messages_received_total", topic="objects") > 20
                and safety.total("fogfleet_messages_received_total", topic="plan") >= 2
            ):
                return False
        return True

    # scan goes robot -> edge/cloud (the planner), plan comes back (the safety module)
    kube.wait_for("each robot's planner and safety module hearing their inputs",
                  _not_yet(heard), 240, 3)  # fmt: skip
    leaks = {}
    for pod in pods:
        m = _metrics(kube, ns, pod)
        assert any(n.startswith("fogfleet_") for n, _, _ in m.series), pod["metadata"]["name"]
        leaks[pod["metadata"]["name"]] = m.total("fogfleet_foreign_messages_total")
    print(f"messages from another robot, per pod: {leaks}")
    assert sum(leaks.values()) == 0, f"cross-robot messages: {leaks}"


def test_the_onboard_standby_takes_over_when_the_offloaded_detector_goes_away(
    kube: Kube, ready: Portable
) -> None:
    ns, topo = ready.namespace, ready.topology
    planned = _placement(kube, ns)
    robot, other = topo.robots
    assert planned[(robot, DETECTOR)] in topo.offload, (
        f"the detector of {robot} was planned on {planned[(robot, DETECTOR)]}: nothing to fall "
        "back from (the edge/cloud nodes have no room for it?)"
    )
    pods = _module_pods(kube, ns)
    remote = _pod(pods, robot, DETECTOR)
    standby, safety = _pod(pods, robot, DETECTOR, standby=True), _pod(pods, robot, SAFETY)
    others = (
        [_pod(pods, other, DETECTOR, standby=True)] if planned[(other, DETECTOR)] != other else []
    )

    def idle(pod: Obj) -> bool:
        return _metrics(kube, ns, pod).total("fogfleet_fallback_active") == 0.0

    kube.wait_for(f"{robot}'s standby idle while the remote detector serves",
                  _not_yet(lambda: idle(standby)), 120, 2)  # fmt: skip
    assert _metrics(kube, ns, standby).has("fogfleet_fallback_active"), "not a standby"

    before = _metrics(kube, ns, standby).total("fogfleet_fallback_takeovers_total")
    others_before = [
        _metrics(kube, ns, p).total("fogfleet_fallback_takeovers_total") for p in others
    ]
    objects = _metrics(kube, ns, safety).total("fogfleet_messages_received_total", topic="objects")
    kube.kubectl("delete", "pod", remote["metadata"]["name"], "-n", ns, "--wait=false")

    def took_over() -> bool:
        return _metrics(kube, ns, standby).total("fogfleet_fallback_takeovers_total") > before

    kube.wait_for(f"{robot}'s standby taking over", _not_yet(took_over), 60, 1)
    # the safety module keeps getting objects, now from its own robot
    kube.wait_for(
        "objects at the safety module after the takeover",
        _not_yet(lambda: _metrics(kube, ns, safety).total(
            "fogfleet_messages_received_total", topic="objects") > objects + 20),
        60, 2,
    )  # fmt: skip
    # the replacement (same node: the plan did not change) serves again and the standby hands back
    kube.wait_for(
        "a replacement remote detector Ready where planned",
        _not_yet(lambda: any(
            p["metadata"]["uid"] != remote["metadata"]["uid"] and _ready(p)
            and p["spec"]["nodeName"] == planned[(robot, DETECTOR)]
            for p in [_pod(_module_pods(kube, ns), robot, DETECTOR)]
        )),
        180, 2,
    )  # fmt: skip
    kube.wait_for(f"{robot}'s standby handing back", _not_yet(lambda: idle(standby)), 120, 2)
    # the other robot never noticed, and nothing was re-planned
    after = [_metrics(kube, ns, p).total("fogfleet_fallback_takeovers_total") for p in others]
    assert after == others_before, (after, others_before)
    assert _placement(kube, ns) == planned
