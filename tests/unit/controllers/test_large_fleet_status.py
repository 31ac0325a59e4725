"""A fleet with more instances than PLACEMENT_LIST_LIMIT: its status lists no per-instance
placement (the object would approach etcd's limit) but holds it in compact form, says per
module where its instances run, and the modules' and ComputeNodes' usage still counts every
instance."""

from __future__ import annotations

import copy
from collections import Counter

import pytest

import fogfleet.controllers.fleet.status as fleet_status
from fogfleet.api.v1alpha1.placement import CompactPlacement
from fogfleet.commandline.cli.planning import recorded_placement
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.measure.usage import reconcile_usage
from fogfleet.errors import InvalidSpec

KEY = ("warehouse", "warehouse")


def settle(kube, deps) -> dict:
    """Plan, run every pod, refresh: the fleet's status once Ready."""
    reconcile(kube.get_fleet(*KEY), deps)
    kube.run_pods()
    out = reconcile(kube.get_fleet(*KEY), deps)
    assert out.ready
    return kube.fleets[KEY]["status"]


def usage(kube) -> tuple[dict, dict]:
    return (
        {n: (m["status"]["instances"], m["status"]["split"]) for n, m in kube.modules.items()},
        {n: (c["status"]["instances"], c["status"]["cpuPlanned"])
         for n, c in kube.compute_nodes.items()},
    )  # fmt: skip


@pytest.fixture
def listed(kube, deps):
    """The same fleet under the normal limit: (its status, the usage it yields)."""
    status = copy.deepcopy(settle(kube, deps))
    reconcile_usage(deps)
    return status, usage(kube)


def test_a_large_fleet_lists_no_instances_but_counts_them_per_module(
    kube, listed, make_deps, monkeypatch
):
    small_status, _ = listed
    assert len(small_status["placement"]) == small_status["modulesPlaced"] > 3
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    status = settle(kube, make_deps())
    assert status["placement"] == []  # cleared, not left stale by the merge patch
    assert status["modulesPlaced"] == small_status["modulesPlaced"]
    per_module = Counter()
    for e in small_status["placement"]:
        per_module[(e["module"], e["tier"])] += 1
    assert status["placementByModule"] == small_status["placementByModule"]
    for row in status["placementByModule"]:
        for tier in ("robot", "edge", "cloud"):
            assert row[tier] == per_module[(row["module"], tier)], (row, tier)
    assert (
        sum(r["robot"] + r["edge"] + r["cloud"] for r in status["placementByModule"])
        == (status["modulesPlaced"])
    )
    entries = small_status["placement"]
    listed = sorted(({k: v for k, v in e.items() if k != "split"} for e in entries), key=repr)
    compact = CompactPlacement.model_validate(status["placementCompact"]).entries()
    assert sorted(compact, key=repr) == listed


def test_a_status_write_sends_only_what_changed(kube, make_deps, monkeypatch):
    """The compact placement is sent when the plan changes it, not at every rollout step."""
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    settle(kube, make_deps())
    patches = kube.status_patches
    assert len(patches) >= 2
    assert sum("placementCompact" in p for p in patches) == 1, [sorted(p) for p in patches]
    assert "placementCompact" in patches[0] and "conditions" in patches[-1]


def test_a_fleet_that_shrinks_below_the_limit_drops_its_compact_form(kube, make_deps, monkeypatch):
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    deps = make_deps()
    assert settle(kube, deps)["placementCompact"]
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 1000)
    status = settle(kube, deps)
    assert status["placement"] and "placementCompact" not in status  # removed by the patch


def test_usage_counts_a_large_fleet_from_what_its_reconcile_found(
    kube, listed, make_deps, monkeypatch
):
    _, small_usage = listed
    for obj in [*kube.modules.values(), *kube.compute_nodes.values()]:
        obj.pop("status", None)
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    deps = make_deps()  # a fresh operator: no placements from the listed run
    settle(kube, deps)
    assert kube.fleets[KEY]["status"]["placement"] == []
    reconcile_usage(deps)
    assert usage(kube) == small_usage


def test_usage_counts_a_large_fleet_from_its_status_after_a_restart(
    kube, listed, make_deps, monkeypatch
):
    """A new operator counts a fleet it has not reconciled yet from the compact form."""
    _, small_usage = listed
    for obj in [*kube.modules.values(), *kube.compute_nodes.values()]:
        obj.pop("status", None)
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    settle(kube, make_deps())
    reconcile_usage(make_deps())  # a fresh operator: only the fleet's status to go by
    assert usage(kube) == small_usage


def test_simulating_a_large_fleets_status_reads_its_compact_placement(
    kube, listed, deps, monkeypatch
):
    small_status, _ = listed
    problem = deps.store.state(KEY).rendered.problem
    small = recorded_placement(problem, {"status": small_status}, "small.yaml")
    monkeypatch.setattr(fleet_status, "PLACEMENT_LIST_LIMIT", 3)
    settle(kube, deps)
    large = copy.deepcopy(kube.fleets[KEY])
    placement, alloc = recorded_placement(problem, large, "fleet.yaml")
    assert (placement == small[0]).all() and (placement >= 0).all()
    assert (alloc.cpu_request == small[1].cpu_request).all()
    large["status"].pop("placementCompact")
    with pytest.raises(InvalidSpec) as err:
        recorded_placement(problem, large, "fleet.yaml")
    assert err.value.field == "status.placement" and "fogfleet plan --json" in str(err.value)
