"""kubectl fogfleet over a fake cluster holding the warehouse example (a fake Source: the
objects as the API server sends them), its output formats and its argument errors."""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.loader import load_paths
from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.commandline.kubectl.cli import main
from fogfleet.domain.build import build_problem
from fogfleet.scheduling.heuristics import greedy_schedule

WAREHOUSE = Path(__file__).resolve().parents[4] / "manifests" / "examples" / "warehouse"
Obj = dict[str, Any]
TAKEOVER_AT = 1_795_000_000.0  # a standby's last takeover in the fixture; `top` runs 150 s later


@cache
def _objects() -> tuple[Obj, list[Obj], list[Obj]]:
    docs = [
        d for f in sorted(WAREHOUSE.glob("*.yaml")) for d in yaml.safe_load_all(f.read_text()) if d
    ]
    fleet = next(d for d in docs if d["kind"] == "RobotFleet")
    modules = [d for d in docs if d["kind"] == "SoftwareModule"]
    nodes = [d for d in docs if d["kind"] == "ComputeNode"]
    cat = load_paths([str(WAREHOUSE)])
    problem = build_problem(cat.fleets[0], cat)
    x = greedy_schedule(problem, SchedulerSettings(seed=1)).placement
    fleet = copy.deepcopy(fleet)
    fleet["metadata"]["namespace"] = "warehouse"
    fleet["status"] = {
        "predictedMissRate": 0.001,
        "split": "20/21/0",
        "placement": [
            {
                "robot": inst.robot,
                "module": inst.module,
                "replica": inst.replica,
                "node": problem.nodes[int(j)].node_name,
                "tier": problem.nodes[int(j)].tier.value,
            }
            for inst, j in zip(problem.instances, x, strict=True)
        ],
        "links": [{"robot": "robot-2", "standbysActive": ["nav-motion-planning"]}],
        "measuredMissRate": 0.0123,
        "fallbacks": [
            {
                "robot": "robot-2",
                "reservedCpu": "500m",
                "standbys": ["nav-motion-planning"],
                "predictedMissRate": 0.0,
                "takeovers": [
                    {
                        "module": "nav-motion-planning",
                        "count": 2,
                        "lastGapSeconds": 0.41,
                        "lastTakeoverTime": timestamp(TAKEOVER_AT),
                        "active": True,
                    }
                ],
            },
            {
                "robot": "robot-3",
                "reservedCpu": "500m",
                "standbys": ["nav-motion-planning"],
                "predictedMissRate": 0.0,
                "takeovers": [{"module": "nav-motion-planning", "count": 0, "active": False}],
            },
        ],
    }
    modules = copy.deepcopy(modules)
    for m in modules:
        if m["metadata"]["name"] == "scene-segmentation":
            m["status"] = {
                "observed": [
                    {"cycles": 300, "missedPercent": 2.0},
                    {"cycles": 100, "missedPercent": 6.0},
                ]
            }
    return fleet, modules, nodes


class FakeCluster:
    """The Source the plugin reads, over fixed objects (every Node Ready)."""

    def __init__(self) -> None:
        self.fleet, self.modules, self.compute_nodes = _objects()

    def get_fleet(self, namespace: str, name: str) -> Obj | None:
        meta = self.fleet["metadata"]
        return self.fleet if (meta["namespace"], meta["name"]) == (namespace, name) else None

    def list_modules(self, namespace: str | None) -> list[Obj]:
        return self.modules

    def list_compute_nodes(self) -> list[Obj]:
        return self.compute_nodes

    def list_nodes(self) -> list[Obj]:
        names = {(c["spec"].get("nodeName") or c["metadata"]["name"]) for c in self.compute_nodes}
        ready = {"conditions": [{"type": "Ready", "status": "True"}]}
        return [{"metadata": {"name": n}, "status": ready} for n in sorted(names)]

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return []

    def list_deployment_metadata(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        return []

    def list_fleets(self, namespace: str | None = None) -> list[Obj]:
        return [self.fleet]

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        return []

    def ask_explanation(self, namespace: str, spec: Mapping[str, Any], seconds: float) -> None:
        return None  # no operator answers (test_why_asks.py has one)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(
        argv,
        connect=lambda kubeconfig, context: (FakeCluster(), "warehouse"),
        clock=lambda: TAKEOVER_AT + 150,
    )
    out = capsys.readouterr()
    return code, out.out, out.err


def test_why_table_names_the_node_and_each_refusal(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(["why", "warehouse", "nav-controller", "--robot", "robot-3"], capsys)
    assert code == 0
    assert "robot-3/nav-controller   robot-3" in out
    assert out.count("taxonomy") == 6
    assert "predicted miss rate" in out and "measured -" in out  # no measurement: the CLI's "-"


def test_why_json_has_the_deployed_node_and_the_measured_rate(
    capsys: pytest.CaptureFixture[str],
) -> None:
    fleet, _, _ = _objects()
    code, out, _ = _run(["why", "warehouse", "scene-segmentation", "-o", "json"], capsys)
    assert code == 0
    doc = json.loads(out)
    where = {(e["robot"], e["module"]): e["node"] for e in fleet["status"]["placement"]}
    for inst in doc["instances"]:
        assert inst["node"] == where[(inst["robot"], "scene-segmentation")]
    assert doc["measuredMissRate"] == pytest.approx(0.03)  # (300 x 2% + 100 x 6%) / 400


def test_why_yaml_parses(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(["why", "warehouse", "nav-localization", "-o", "yaml"], capsys)
    assert code == 0
    doc = yaml.safe_load(out)
    assert {a["rule"] for i in doc["instances"] for a in i["alternatives"]} == {"device"}


def test_top_shows_measured_and_predicted_and_active_fallbacks(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = _run(["top", "warehouse", "-o", "json"], capsys)
    assert code == 0
    doc = json.loads(out)
    seg = next(m for m in doc["modules"] if m["module"] == "scene-segmentation")
    assert seg["measuredMissRate"] == pytest.approx(0.03)
    assert seg["predictedMissRate"] is not None and seg["cpuRequested"] > 0
    nav = next(m for m in doc["modules"] if m["module"] == "nav-motion-planning")
    assert nav["fallbacksActive"] == ["robot-2"]
    code, table, _ = _run(["top", "warehouse"], capsys)
    assert "MEASURED-MISS" in table and "3.0%" in table  # format_miss_rate: one decimal from 1 %


def test_top_shows_the_fleets_measured_rate_and_the_standbys_last_takeover(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = _run(["top", "warehouse", "-o", "json"], capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["measuredMissRate"] == 0.0123, "the operator's status.measuredMissRate"
    assert doc["takeovers"] == 2
    nav = next(m for m in doc["modules"] if m["module"] == "nav-motion-planning")
    assert [t["robot"] for t in nav["takeovers"]] == ["robot-2", "robot-3"]
    last = nav["lastTakeover"]
    assert last["robot"] == "robot-2" and last["gapSeconds"] == 0.41
    assert last["agoSeconds"] == 150
    seg = next(m for m in doc["modules"] if m["module"] == "scene-segmentation")
    assert seg["takeovers"] == [] and seg["lastTakeover"] is None
    code, out, _ = _run(["top", "warehouse", "-o", "yaml"], capsys)
    same = yaml.safe_load(out)
    assert same.keys() == doc.keys() and same["takeovers"] == 2
    assert (
        next(m for m in same["modules"] if m["module"] == "nav-motion-planning")[
            "lastTakeover"
        ].keys()
        == last.keys()
    )
    code, table, _ = _run(["top", "warehouse"], capsys)
    lines = table.splitlines()
    assert "TAKEOVERS" in lines[0] and lines[1].split()[-1] == "2"
    assert "1.2%" in lines[1]  # MEASURED-MISS: the fleet's own rate
    nav_line = next(line for line in lines if line.startswith("nav-motion-planning"))
    assert nav_line.endswith("0.41 s, 2m ago (robot-2)")
    seg_line = next(line for line in lines if line.startswith("scene-segmentation"))
    assert seg_line.endswith("-")


def test_unknown_fleet_and_module_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(["why", "nope", "nav-controller"], capsys)
    assert code == 2 and "not found" in err
    code, _, err = _run(["why", "warehouse", "nope"], capsys)
    assert code == 2 and "no instance of module nope" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["why", "warehouse"],
        ["why", "warehouse", "m", "-o", "wide"],
        ["plan", "warehouse", "--without-node", "edge-1"],
        ["plan", "warehouse", "--what-if"],
        ["plan", "warehouse", "--what-if", "--add-robot", "robot-6"],
        ["plan", "warehouse", "--what-if", "--link", "robot-1"],
    ],
)
def test_bad_arguments_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        _run(argv, capsys)
    assert exc.value.code == 2


@pytest.mark.parametrize("limit", ["0", "-1", "x"])
def test_why_limit_below_one_exits_2(limit: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:  # argparse, naming the option (0 was a traceback)
        _run(["why", "warehouse", "nav-controller", "--limit", limit], capsys)
    assert exc.value.code == 2
    assert "--limit" in capsys.readouterr().err


class CrowdedCluster(FakeCluster):
    """The warehouse beside another fleet whose plan claims 10 cores of edge-1, and a pod of
    another team that requests 1 core there."""

    def list_fleets(self, namespace: str | None = None) -> list[Obj]:
        other = {
            "metadata": {"name": "other", "namespace": "north"},
            "status": {"placement": [{"robot": "r", "module": "m", "node": "edge-1", "cpu": "10"}]},
        }
        return [self.fleet, other]

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        return [
            {
                "metadata": {"namespace": "team", "labels": {}},
                "spec": {"nodeName": "edge-1"},
                "requests": {"cpu": 1.0, "memory": 0.0},
            }
        ]


def test_the_plugin_plans_around_the_room_other_fleets_and_pods_hold() -> None:
    """One site with the operator: the fleet's problem has edge-1 less what others hold."""
    from fogfleet.commandline.kubectl.live import read_fleet

    alone = read_fleet(FakeCluster(), "warehouse", "warehouse")
    crowded = read_fleet(CrowdedCluster(), "warehouse", "warehouse")
    j = next(k for k, n in enumerate(alone.problem.nodes) if n.name == "edge-1")
    assert alone.problem.capacity[j, 0] - crowded.problem.capacity[j, 0] == pytest.approx(11)
    assert (
        crowded.snapshot.held["edge-1"].itemised()
        == "pods in team 1, RobotFleet north/other 10 cores"
    )


def test_why_names_the_fleets_and_pods_that_fill_a_node(capsys: pytest.CaptureFixture[str]) -> None:
    """A node too full for a move says who else holds it, in cores, as `explain` does."""
    code = main(
        ["why", "warehouse", "scene-segmentation", "-o", "json"],
        connect=lambda kubeconfig, context: (CrowdedCluster(), "warehouse"),
        clock=lambda: TAKEOVER_AT + 150,
    )
    out = capsys.readouterr()
    assert code == 0
    full = [
        a["reason"]
        for i in json.loads(out.out)["instances"]
        for a in i["alternatives"]
        if a["rule"] == "capacity" and a["node"] == "edge-1"
    ]
    assert full, "edge-1, less 11 cores, is too full for a segmentation instance"
    assert all(
        "other fleets and pods hold 11 more there (pods in team 1, RobotFleet north/other 10 cores)"
        in r
        for r in full
    ), full
    assert "Shared nodes of warehouse/warehouse: other fleets and pods hold 11 cores" in out.err


class LargeFleetCluster(FakeCluster):
    """A fleet whose status lists no placement (issue 46): it is read from its Deployments,
    whose metadata names their node (``fogfleet.io/node``) unless ``old``."""

    def __init__(self, old: bool = False) -> None:
        super().__init__()
        self.fleet = copy.deepcopy(self.fleet)
        self.fleet["status"].pop("placement", None)
        self.calls: list[tuple[str, object]] = []
        self.metadata = [
            {
                "metadata": {
                    "name": f"warehouse-robot-{k}-nav-controller",
                    "labels": {"fogfleet.io/fleet": "warehouse"},
                    "annotations": {
                        "fogfleet.io/robot": f"robot-{k}",
                        "fogfleet.io/module": "nav-controller",
                        "fogfleet.io/replica": "0",
                        **({} if old and k == 2 else {"fogfleet.io/node": f"robot-{k}"}),
                    },
                }
            }
            for k in (1, 2)
        ]

    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        self.calls.append(("whole", dict(selector)))
        return []

    def list_deployment_metadata(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]:
        self.calls.append(("metadata", dict(selector)))
        return copy.deepcopy(self.metadata)

    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]:
        self.calls.append(("pods besides", besides))
        return []


def test_a_fleet_whose_status_holds_its_placement_is_read_without_its_deployments() -> None:
    """Issue 46: at 1000 robots the Deployments' metadata alone was 43 MiB and most of `why`'s
    time; the status's compact placement says the same in a few KiB."""
    from fogfleet.api.v1alpha1.placement import CompactPlacement
    from fogfleet.commandline.kubectl.live import read_fleet

    listed = LargeFleetCluster()
    listed.fleet["status"]["placement"] = copy.deepcopy(FakeCluster().fleet["status"]["placement"])
    compact = LargeFleetCluster()
    compact.fleet["status"]["placementCompact"] = CompactPlacement.of(
        listed.fleet["status"]["placement"]
    ).wire()
    read = [read_fleet(c, "warehouse", "warehouse") for c in (listed, compact)]
    for cluster in (listed, compact):
        assert [c[0] for c in cluster.calls] == ["pods besides"]  # no Deployment read
    assert (read[0].placement == read[1].placement).all() and (read[0].placement >= 0).all()
    assert (read[1].problem.current == read[1].placement).all()  # runs where the status says


def test_a_large_fleets_placement_is_read_from_its_deployments_metadata() -> None:
    """The plugin's read of a large fleet is bounded (issue 46): the Deployments' metadata, not
    the Deployments, and every Pod but the fleet's own; Deployments written before the node
    annotation existed are read whole."""
    from fogfleet.commandline.kubectl.live import read_fleet

    cluster = LargeFleetCluster()
    live = read_fleet(cluster, "warehouse", "warehouse")
    assert sorted(c[0] for c in cluster.calls) == ["metadata", "pods besides"]  # side by side
    assert ("pods besides", ("warehouse", "warehouse")) in cluster.calls
    nodes = [n.name for n in live.problem.nodes]
    placed = {live.problem.label(i): nodes[j] for i, j in enumerate(live.placement) if j >= 0}
    assert placed == {"robot-1/nav-controller": "robot-1", "robot-2/nav-controller": "robot-2"}

    old = LargeFleetCluster(old=True)
    read_fleet(old, "warehouse", "warehouse")
    assert sorted(c[0] for c in old.calls) == ["metadata", "pods besides", "whole"]
    assert old.calls.index(("metadata", {"fogfleet.io/fleet": "warehouse"})) < old.calls.index(
        ("whole", {"fogfleet.io/fleet": "warehouse"})
    )
