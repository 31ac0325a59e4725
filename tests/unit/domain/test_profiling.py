"""Automatic profiling, the pure part: which limits, the fit, where a profile is needed."""

from __future__ import annotations

from typing import Any

import pytest

from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.profiling import ProfilingRun, ProfilingStatus
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.profiling import (
    Measurement,
    edge_cases,
    fit_profile,
    grid_for,
    module_spec_hash,
    needed_profiles,
    with_profiled,
)
from fogfleet.errors import InvalidSpec


def _module(**spec: Any) -> SoftwareModule:
    body: dict[str, Any] = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "SoftwareModule",
        "metadata": {"name": "mapper", "namespace": "ns"},
        "spec": {
            "template": {"image": "registry.local/mapper:1", "args": ["--cpu-work", "20"]},
            "taxonomy": {
                "executionPattern": "continuous",
                "realtime": "soft",
                "safety": "relevant",
            },
            "cycleTimeMillis": 200,
            "resources": {"cpu": "100m", "memory": "128Mi"},
            "profile": [{"hardwareType": "edge-x", "cpu": "100m", "meanMillis": 20}],
            "profiling": {"mode": "auto", "cpus": ["50m", "100m", "150m", "200m"]},
            **spec,
        },
    }
    mod = parse_object(body)
    assert isinstance(mod, SoftwareModule)
    return mod


def _node(name: str, tier: str, hw: str, cpu: str = "400m") -> ComputeNode:
    node = parse_object(
        {
            "apiVersion": "fogfleet.io/v1alpha1",
            "kind": "ComputeNode",
            "metadata": {"name": name},
            "spec": {"tier": tier, "hardwareType": hw, "capacity": {"cpu": cpu, "memory": "1Gi"}},
        }
    )
    assert isinstance(node, ComputeNode)
    return node


NODES = [
    _node("r1", "robot", "robot-x"),
    _node("r2", "robot", "robot-x"),
    _node("e1", "edge", "edge-x", "1"),
]


def test_edge_cases_are_the_ends_and_the_geometric_middle() -> None:
    assert edge_cases([0.05, 0.1, 0.2, 0.4, 0.8]) == [0.05, 0.2, 0.8]
    assert edge_cases([0.2, 0.05, 0.15, 0.1]) == [0.05, 0.1, 0.2]
    assert edge_cases([0.5, 1.0, 2.0, 4.0]) == [0.5, 1.0, 4.0]  # a tie: the smaller
    assert edge_cases([0.3, 0.1]) == [0.1, 0.3]  # a small grid is measured whole


def test_work_over_cpu_plus_a_constant_is_interpolated_exactly() -> None:
    # t(c) = 2 ms + 10 ms / c, a line in 1/c; spreads a tenth of the means
    measured = [Measurement(c, 2 + 10 / c, (2 + 10 / c) / 10, 50) for c in (0.05, 0.2, 0.8)]
    fit = fit_profile("robot-x", [0.05, 0.1, 0.2, 0.4, 0.8], measured)
    assert fit.error_percent == pytest.approx(0, abs=1e-6)
    rows = {r.cpu: r for r in fit.rows}
    assert [r.cpu for r in fit.rows] == ["50m", "100m", "200m", "400m", "800m"]
    assert rows["100m"].source == "fitted" and rows["100m"].mean_millis == pytest.approx(102)
    assert rows["100m"].std_millis == pytest.approx(10.2)
    assert rows["400m"].mean_millis == pytest.approx(27)
    assert rows["50m"].source == "measured" and rows["50m"].cycles == 50


def test_a_quota_staircase_stays_between_its_neighbours_and_says_how_far_off_it_may_be() -> None:
    # measured on the bed: 10 ms of CPU work at 50m, 100m and 200m (CFS quota per 100 ms)
    measured = [
        Measurement(0.05, 185, 32, 20),
        Measurement(0.1, 24, 24, 20),
        Measurement(0.2, 28, 6.5, 20),
    ]
    fit = fit_profile("bed-robot", [0.05, 0.1, 0.15, 0.2], measured)
    mid = next(r for r in fit.rows if r.cpu == "150m")
    assert mid.source == "fitted" and 24 <= mid.mean_millis <= 28
    assert mid.mean_millis == pytest.approx(28 - (1 / 0.15 - 5) / 5 * 4, abs=1e-3)
    # the ends predict 100m at 80 ms, it measured 24: the fitted rows are flagged as rough
    assert fit.error_percent == pytest.approx((28 + 5 / 15 * 157 - 24) / 24 * 100, rel=1e-3)
    assert fit_profile("x", [0.1, 0.2], measured[1:]).error_percent is None  # two: unknown


def test_grid_keeps_the_limits_a_node_of_the_type_can_give() -> None:
    assert grid_for(_module(), [0.12, 0.15]) == [0.05, 0.1, 0.15]
    assert grid_for(_module(), []) == []


def test_a_module_needs_profiles_where_it_may_run_and_has_no_rows() -> None:
    needs = needed_profiles([_module()], NODES)
    assert {hw: [n.metadata.name for n in ns] for hw, ns in needs["mapper"].items()} == {
        "robot-x": ["r1", "r2"]
    }
    # not where its tiers do not allow it, nor with default rows, nor with profiling off
    assert needed_profiles([_module(requirements={"tiers": ["edge"]})], NODES) == {}
    default = [{"hardwareType": "default", "cpu": "100m", "meanMillis": 20}]
    assert needed_profiles([_module(profile=default)], NODES) == {}
    assert needed_profiles([_module(profiling={"mode": "off"})], NODES) == {}
    # a shared module never runs on a robot; a critical one only there
    assert needed_profiles([_module(scope="shared")], NODES) == {}
    critical = _module(
        taxonomy={"executionPattern": "periodic", "realtime": "hard", "safety": "critical"},
        profile=[],
    )
    assert set(needed_profiles([critical], NODES)["mapper"]) == {"robot-x"}


def test_profiled_rows_of_the_current_spec_join_the_profile() -> None:
    mod = _module()
    spec_hash = module_spec_hash(mod)
    fit = fit_profile(
        "robot-x", [0.05, 0.1, 0.2], [Measurement(0.05, 400, 40, 20), Measurement(0.2, 100, 10, 20)]
    )
    run = ProfilingRun(
        hardware_type="robot-x",
        state="Profiled",
        jobs=2,
        grid=3,
        spec_hash=spec_hash,
        last_update="2026-11-25T00:00:00Z",
    )
    status = ProfilingStatus(runs=[run], rows=list(fit.rows)).wire()
    got = with_profiled(mod, {"status": {"profiling": status}})
    rows = {(r.hardware_type, str(r.cpu)) for r in got.spec.profile}
    assert ("robot-x", "100m") in rows and ("edge-x", "100m") in rows and len(rows) == 4
    # a run of another spec (the container changed since) is not used
    stale = ProfilingStatus(
        runs=[run.model_copy(update={"spec_hash": "other"})], rows=list(fit.rows)
    )
    assert len(with_profiled(mod, {"status": {"profiling": stale.wire()}}).spec.profile) == 1
    # nor a status written in another shape
    assert with_profiled(mod, {"status": {"profiling": {"runs": "?"}}}) == mod


def test_the_spec_hash_follows_the_container_not_the_declared_rows() -> None:
    base = module_spec_hash(_module())
    assert module_spec_hash(_module(profile=[])) == base
    assert module_spec_hash(_module(template={"image": "registry.local/mapper:2"})) != base
    assert module_spec_hash(_module(profiling={"mode": "auto", "cycles": 99})) != base


def test_a_profile_may_be_empty_only_when_profiled_automatically() -> None:
    with pytest.raises(InvalidSpec, match=r"profile: at least one row, unless profiling\.mode"):
        _module(profile=[], profiling=None)
    assert _module(profile=[]).spec.profile == []
    with pytest.raises(InvalidSpec, match=r"profiling\.cpus: 100m listed more than once"):
        _module(profiling={"mode": "auto", "cpus": ["100m", "0.1"]})
    with pytest.raises(InvalidSpec, match=r"profiling.cpus\[0\]: must be greater than zero"):
        _module(profiling={"mode": "auto", "cpus": ["0m"]})


def _split_network(profiles: list[dict[str, Any]]) -> SoftwareModule:
    """A split network (``spec.dnn``) whose times profiling measures, with ``profiles``."""
    dnn = {
        "accuracy": 0.9,
        "splitPoints": [{"name": "bneck"}],
        "localModel": {"name": "tiny", "accuracy": 0.6},
        "profiles": profiles,
    }
    return _module(profile=[], profiling={"mode": "auto"}, dnn=dnn)


def test_a_split_network_needs_a_profile_on_every_type_it_may_use_that_has_none() -> None:
    needs = needed_profiles([_split_network([])], NODES)
    assert set(needs["mapper"]) == {"robot-x", "edge-x"}  # the heads' type and the tails'
    robot = {
        "hardwareType": "robot-x",
        "inputBytes": 100,
        "outputBytes": 10,
        "fullMillis": 9,
        "localMillis": 1,
        "splitPoints": [{"name": "bneck", "headMillis": 5, "tailMillis": 4, "tensorBytes": 8}],
    }
    assert set(needed_profiles([_split_network([robot])], NODES)["mapper"]) == {"edge-x"}
    # what a Job times depends on the split points' names
    assert module_spec_hash(_split_network([])) != module_spec_hash(_module(profile=[]))
