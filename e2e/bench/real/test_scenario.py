"""The paper fleet and the paper bed agree, and the bed profile is chosen by name (pure)."""

from __future__ import annotations

import pytest

from e2e.bed.base import HarnessError
from e2e.bed.realnodes import PROFILES, declared, profile_nodes
from e2e.bench.real.protocol import PERCEPTION
from e2e.bench.real.scenario import PROFILE, Scenario
from fogfleet.api.v1alpha1.base import parse_cpu


def test_the_fleets_computenodes_are_the_paper_beds_real_nodes() -> None:
    bed = {n.name: n for n in profile_nodes(PROFILE)}
    nodes = Scenario().nodes()
    assert {n["metadata"]["name"] for n in nodes} == set(bed)
    for n in nodes:
        real = bed[n["metadata"]["name"]]
        # the planner's capacity is the node's CFS quota, and its rows are chosen by the same
        # hardware type kube-scheduler sees on the Node
        assert round(parse_cpu(n["spec"]["capacity"]["cpu"]) * 1000) == real.cpu_millis
        assert n["spec"]["hardwareType"] == real.labels["fogfleet.io/hardware-type"]
        assert n["spec"]["tier"] == real.labels["fogfleet.io/tier"]


def test_the_bed_is_the_issues_two_pi_robots_and_two_unequal_edges() -> None:
    cpus = sorted((n.labels["fogfleet.io/tier"], n.cpu_millis) for n in profile_nodes("paper"))
    assert cpus == [("edge", 300), ("edge", 800), ("robot", 300), ("robot", 300)]


def test_the_pi_runs_the_perception_four_times_slower_and_navigation_as_declared() -> None:
    scenario = Scenario()
    modules = {m["metadata"]["name"]: m for m in scenario.of_kind("SoftwareModule")}
    for name, m in modules.items():
        rows = m["spec"]["profile"]
        pi = {r["cpu"]: r for r in rows if r["hardwareType"] == "pi4"}
        i9 = {r["cpu"]: r for r in rows if r["hardwareType"] == "default"}
        if name in PERCEPTION:
            assert set(pi) == set(i9)
            for cpu, row in pi.items():
                assert row["meanMillis"] == 4 * i9[cpu]["meanMillis"]
        else:
            assert not pi  # the navigation rows stay as declared on the Pi
    # on board, no perception row meets its deadline: placement decides the primary endpoint
    problem = scenario.problem
    pi_node = next(j for j, n in enumerate(problem.nodes) if n.name == "paper-robot-1")
    for i, inst in enumerate(problem.instances):
        if inst.module in PERCEPTION and inst.robot == "paper-robot-1":
            assert problem.nominal.exe_mean[i, pi_node] > problem.cycle[i]


def test_profiles_are_known_by_name_and_their_node_names_never_collide() -> None:
    assert set(PROFILES) == {"default", "paper"}
    names = [n.name for p in PROFILES for n in profile_nodes(p)]
    assert len(names) == len(set(names))
    assert declared("paper-edge-2").cpu_millis == 300
    assert declared("bed-edge-1").cpu_millis == 1000
    with pytest.raises(HarnessError, match="unknown bed profile 'lab': one of default, paper"):
        profile_nodes("lab")
    with pytest.raises(HarnessError, match="no bed profile declares a real node 'nope'"):
        declared("nope")
