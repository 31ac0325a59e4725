"""The portable e2e suite's pure parts: which Nodes it uses, the objects it applies, the chart
arguments and the metrics parser (e2e/portable)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from e2e.portable import chart, nodes
from e2e.portable.fleet import DETECTOR, MODULES, PLANNER, fleet_objects
from e2e.portable.metrics import parse
from e2e.portable.settings import Settings, split_image

from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.commandline.cli import main


def node(name: str, tier: str | None, hw: str = "hw", **extra: Any) -> dict[str, Any]:
    labels = {"fogfleet.io/hardware-type": hw, **extra.pop("labels", {})}
    if tier:
        labels["fogfleet.io/tier"] = tier
    return {
        "metadata": {"name": name, "labels": labels, "annotations": extra.pop("annotations", {})},
        "spec": extra.pop("spec", {}),
        "status": {"conditions": [{"type": "Ready", "status": extra.pop("ready", "True")}]},
    }


BED = [
    node("bed-robot-1", "robot", "bed-robot", labels={"fogfleet.io/e2e-real": "true"}),
    node("bed-robot-2", "robot", "bed-robot", labels={"fogfleet.io/e2e-real": "true"}),
    node("bed-edge-1", "edge", "bed-edge", labels={"fogfleet.io/e2e-real": "true"}),
    node("robot-1", "robot", annotations={"kwok.x-k8s.io/node": "fake"}),
    node("edge-1", "edge", annotations={"kwok.x-k8s.io/node": "fake"}),
]


def test_on_the_bed_the_real_nodes_are_used_and_the_operator_is_pinned_to_them() -> None:
    topo = nodes.pick(BED)
    assert topo.robots == ("bed-robot-1", "bed-robot-2") and topo.offload == ("bed-edge-1",)
    assert topo.node_selector == {"fogfleet.io/e2e-real": "true"}


def test_without_the_real_label_every_labelled_usable_node_counts_and_nothing_is_pinned() -> None:
    topo = nodes.pick([node("r2", "robot"), node("r1", "robot"), node("r3", "robot"),
                       node("cloud", "cloud"), node("cp", None)])  # fmt: skip
    assert topo.robots == ("r1", "r2") and topo.offload == ("cloud",)
    assert topo.node_selector == {}


@pytest.mark.parametrize(
    ("bad", "why"),
    [
        (node("r2", "robot", annotations={"kwok.x-k8s.io/node": "fake"}), "a kwok fake"),
        (node("r2", "robot", ready="False"), "not Ready"),
        (node("r2", "robot", spec={"unschedulable": True}), "cordoned"),
        (node("r2", "robot", spec={"taints": [{"key": "x", "effect": "NoSchedule"}]}),
         "tainted x"),
        (node("r2", "tower"), "no fogfleet.io/tier label of robot/edge/cloud"),
    ],
)  # fmt: skip
def test_a_node_that_cannot_run_the_fleet_is_not_used_and_the_refusal_says_why(
    bad: dict[str, Any], why: str
) -> None:
    with pytest.raises(nodes.NotEnoughNodes) as err:
        nodes.pick([node("r1", "robot"), bad, node("e1", "edge")])
    assert f"r2 ({why})" in str(err.value) and "robots ['r1']" in str(err.value)


def test_a_prefer_no_schedule_taint_does_not_keep_a_node_out() -> None:
    soft = node("r2", "robot", spec={"taints": [{"key": "x", "effect": "PreferNoSchedule"}]})
    assert nodes.pick([node("r1", "robot"), soft, node("e1", "edge")]).robots == ("r1", "r2")


def test_the_applied_objects_are_valid_custom_resources() -> None:
    topo = nodes.pick(BED)
    for doc in nodes.compute_nodes(topo):
        ComputeNode.model_validate(doc)
    objs = fleet_objects(topo, "ns", "registry:5000/ros2-module:1", "Never")
    kinds = {"SoftwareModule": SoftwareModule, "RobotFleet": RobotFleet}
    for doc in objs:
        kinds[doc["kind"]].model_validate(doc)
    modules = [o for o in objs if o["kind"] == "SoftwareModule"]
    assert [m["metadata"]["name"] for m in modules] == list(MODULES)
    assert {m["spec"]["template"]["imagePullPolicy"] for m in modules} == {"Never"}
    # every profile row names a hardware type the cluster's nodes have
    rows = {r["hardwareType"] for m in modules for r in m["spec"]["profile"]}
    assert rows == {"bed-robot", "bed-edge"}


@pytest.mark.parametrize(
    ("robot_cpu", "edge_cpu"), [("400m", "1000m"), ("4", "8")], ids=["bed", "kind"]
)
def test_the_fleet_plans_its_detector_and_planner_off_the_robots(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], robot_cpu: str, edge_cpu: str
) -> None:
    """What the fallback and cross-node tests need, checked by the planner offline on the
    bed's shares and on a laptop's kind nodes."""
    topo = nodes.pick(BED)
    docs = nodes.compute_nodes(topo)
    for doc in docs:
        cpu = robot_cpu if doc["spec"]["tier"] == "robot" else edge_cpu
        doc["spec"]["capacity"] = {"cpu": cpu, "memory": "1536Mi"}
    docs += fleet_objects(topo, "ns", "img:1", "IfNotPresent")
    (tmp_path / "fleet.yaml").write_text(yaml.safe_dump_all(docs))
    assert main(["plan", str(tmp_path), "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["feasible"] is True
    where = {(p["robot"], p["module"]): p["node"] for p in plan["placement"]}
    for robot in topo.robots:
        assert where[(robot, DETECTOR)] == "bed-edge-1" and where[(robot, PLANNER)] == "bed-edge-1"
        assert where[(robot, "sensor")] == robot and where[(robot, "safety")] == robot


def test_the_chart_is_installed_with_the_image_the_policy_and_the_pin() -> None:
    args = chart.install_args("ns-1", "localhost:5000/fogfleet:0.2", "Never",
                              {"fogfleet.io/e2e-real": "true"})  # fmt: skip
    joined = " ".join(args)
    assert args[:3] == ["install", chart.RELEASE, str(chart.CHART)]
    assert "watchNamespaces={ns-1}" in joined and "replicaCount=1" in joined
    assert "crds.install=false" in joined  # the suite applies them; another release may own them
    assert "image.repository=localhost:5000/fogfleet" in joined and "image.tag=0.2" in joined
    assert "image.pullPolicy=Never" in joined
    assert "nodeSelector.fogfleet\\.io/e2e-real=true" in joined
    assert "nodeSelector" not in " ".join(chart.install_args("n", "a/b:1", "Never", {}))


@pytest.mark.parametrize(
    ("ref", "want"),
    [("ghcr.io/fogfleet/fogfleet:0.1.0", ("ghcr.io/fogfleet/fogfleet", "0.1.0")),
     ("localhost:5000/img", ("localhost:5000/img", "latest")), ("img", ("img", "latest"))],
)  # fmt: skip
def test_an_image_ref_splits_into_repository_and_tag(ref: str, want: tuple[str, str]) -> None:
    assert split_image(ref) == want


def test_settings_refuse_a_missing_helm_and_an_unknown_pull_policy(tmp_path: Path) -> None:
    helm = tmp_path / "helm"
    helm.write_text("")
    with pytest.raises(ValueError, match="FOGFLEET_E2E_HELM"):
        Settings.from_env({"FOGFLEET_E2E_HELM": str(tmp_path / "none"), "PATH": ""})
    with pytest.raises(ValueError, match="FOGFLEET_E2E_PULL_POLICY"):
        Settings.from_env({"FOGFLEET_E2E_HELM": str(helm), "FOGFLEET_E2E_PULL_POLICY": "Maybe"})
    got = Settings.from_env({"FOGFLEET_E2E_HELM": str(helm)})
    assert got.pull_policy == "IfNotPresent" and got.module_image.endswith("ros2-module:0.1.0")


def test_metrics_are_summed_over_the_series_whose_labels_match() -> None:
    m = parse(
        "# HELP fogfleet_messages_received_total Messages received\n"
        'fogfleet_messages_received_total{module="safety",robot="r1",topic="objects"} 12.0\n'
        'fogfleet_messages_received_total{module="safety",robot="r1",topic="plan"} 3.0\n'
        "fogfleet_fallback_active 0.0\n"
    )
    assert m.total("fogfleet_messages_received_total") == 15.0
    assert m.total("fogfleet_messages_received_total", topic="plan") == 3.0
    assert m.total("fogfleet_foreign_messages_total") == 0.0
    assert m.has("fogfleet_fallback_active") and not m.has("fogfleet_foreign_messages_total")


def test_histograms_give_buckets_and_totals_leave_them_out() -> None:
    m = parse(
        "# TYPE fogfleet_input_gap_seconds histogram\n"
        'fogfleet_input_gap_seconds_bucket{topic="a",le="0.1"} 4.0\n'
        'fogfleet_input_gap_seconds_bucket{topic="a",le="+Inf"} 6.0\n'
        'fogfleet_input_gap_seconds_bucket{topic="b",le="+Inf"} 9.0\n'
        'fogfleet_input_gap_seconds_count{topic="a"} 6.0\n'
        'fogfleet_input_gap_seconds_sum{topic="a"} 0.9\n'
        "# TYPE other_total counter\n"
        "other_total 2.0\n"
    )
    assert m.buckets("fogfleet_input_gap_seconds", topic="a") == {0.1: 4.0, float("inf"): 6.0}
    assert m.totals("fogfleet_") == {
        "fogfleet_input_gap_seconds_count": 6.0,
        "fogfleet_input_gap_seconds_sum": 0.9,
    }
    assert m.total("other_total") == 2.0
