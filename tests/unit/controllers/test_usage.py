"""reconcile_usage(): SoftwareModule and ComputeNode status from the plans really deployed."""

from __future__ import annotations

import copy
from collections import Counter

import pytest

from fogfleet.api.v1alpha1.computenode import ComputeNodeStatus
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModuleStatus
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.measure.usage import reconcile_usage
from fogfleet.domain.observed import ModuleDrift

KEY = ("warehouse", "warehouse")


def planned(kube, deps) -> list[dict]:
    reconcile(kube.get_fleet(*KEY), deps)
    return kube.fleets[KEY]["status"]["placement"]


def test_modules_say_which_fleets_place_them_and_where(kube, deps):
    placement = planned(kube, deps)
    assert reconcile_usage(deps) == len(kube.modules) + len(kube.compute_nodes)
    for (_ns, name), module in kube.modules.items():
        status = module["status"]
        mine = [e for e in placement if e["module"] == name]
        tiers = Counter(e["tier"] for e in mine)
        assert status["fleets"] == (["warehouse"] if mine else []), name
        assert status["instances"] == len(mine), name
        assert status["split"] == f"{tiers['robot']}/{tiers['edge']}/{tiers['cloud']}", name
        assert status["observedGeneration"] == module["metadata"]["generation"]
        SoftwareModuleStatus.model_validate(status)  # the CRD's model accepts what we write
    assert sum(m["status"]["instances"] for m in kube.modules.values()) == len(placement)


def test_offloadable_follows_the_taxonomy(kube, deps):
    reconcile_usage(deps)
    verdicts = {name: m["status"]["offloadable"] for (_, name), m in kube.modules.items()}
    for (_, name), module in kube.modules.items():
        tax = module["spec"]["taxonomy"]
        if tax["realtime"] == "hard" or tax["safety"] == "critical":
            assert verdicts[name] == "never", name
        else:
            assert verdicts[name] in ("candidate", "preferred"), name
    assert set(verdicts.values()) >= {"never", "candidate"}


def test_compute_nodes_say_who_uses_them_and_how_much_cpu(kube, deps):
    placement = planned(kube, deps)
    reconcile_usage(deps)
    for name, cn in kube.compute_nodes.items():
        node = cn["spec"].get("nodeName") or name
        here = [e for e in placement if e["node"] == node]
        status = cn["status"]
        assert status["instances"] == len(here), name
        assert status["fleets"] == (["warehouse/warehouse"] if here else []), name
        cores = sum(float(e["cpu"].removesuffix("m")) / (1000 if "m" in e["cpu"] else 1)
                    for e in here)  # fmt: skip
        planned_cpu = status["cpuPlanned"]
        got = float(planned_cpu.removesuffix("m")) / (1000 if planned_cpu.endswith("m") else 1)
        assert abs(got - cores) < 1e-3, name
        ComputeNodeStatus.model_validate(status)


def test_compute_node_ready_condition_follows_its_node(kube, deps):
    name = next(iter(kube.compute_nodes))
    node = kube.compute_nodes[name]["spec"].get("nodeName") or name
    reconcile_usage(deps)
    ready = {c["type"]: c for c in kube.compute_nodes[name]["status"]["conditions"]}["Ready"]
    assert (ready["status"], ready["reason"]) == ("True", "NodeReady")
    assert kube.compute_nodes[name]["status"]["ready"] is True
    kube.set_ready(node, False)
    reconcile_usage(deps)
    ready = {c["type"]: c for c in kube.compute_nodes[name]["status"]["conditions"]}["Ready"]
    assert (ready["status"], ready["reason"]) == ("False", "NodeUnavailable")
    assert "NotReady" in ready["message"] and kube.compute_nodes[name]["status"]["ready"] is False
    del kube.nodes[node]
    reconcile_usage(deps)
    ready = {c["type"]: c for c in kube.compute_nodes[name]["status"]["conditions"]}["Ready"]
    assert (ready["status"], ready["reason"]) == ("False", "NodeNotFound")


def test_a_second_pass_with_nothing_changed_patches_nothing(kube, deps):
    planned(kube, deps)
    assert reconcile_usage(deps) > 0
    before = len(kube.status_patches), len(kube.module_patches)
    assert reconcile_usage(deps) == 0
    assert (len(kube.status_patches), len(kube.module_patches)) == before


def test_a_deleted_fleet_leaves_no_stale_usage(kube, deps):
    planned(kube, deps)
    reconcile_usage(deps)
    del kube.fleets[KEY]
    reconcile_usage(deps)
    for module in kube.modules.values():
        assert (module["status"]["fleets"], module["status"]["instances"]) == ([], 0)
        assert module["status"]["split"] == "0/0/0"
    for cn in kube.compute_nodes.values():
        assert (cn["status"]["fleets"], cn["status"]["instances"]) == ([], 0)
        assert cn["status"]["cpuPlanned"] == "0"


def test_a_fleet_being_deleted_counts_no_more(kube, deps):
    """Foreground deletion keeps the fleet listed, with a deletionTimestamp, while its
    Deployments go: the pass drops it then, not only once it is gone."""
    planned(kube, deps)
    reconcile_usage(deps)
    assert any(cn["status"]["instances"] for cn in kube.compute_nodes.values())
    kube.fleets[KEY]["metadata"]["deletionTimestamp"] = "2025-01-01T00:00:00Z"
    assert reconcile_usage(deps) > 0
    for cn in kube.compute_nodes.values():
        assert (cn["status"]["fleets"], cn["status"]["instances"]) == ([], 0)
    assert all(m["status"]["instances"] == 0 for m in kube.modules.values())


def test_usage_keeps_the_autoscalers_status(kube, deps):
    (ns, name), module = next(iter(kube.modules.items()))
    scaling = {"desiredReplicas": 3, "pools": [{"tier": "edge", "replicas": 3}]}
    module["status"] = {"scaling": copy.deepcopy(scaling), "conditions": [{"type": "Scaling"}]}
    reconcile_usage(deps)
    assert kube.modules[(ns, name)]["status"]["scaling"] == scaling
    assert kube.modules[(ns, name)]["status"]["conditions"] == [{"type": "Scaling"}]


def test_two_fleets_sharing_a_module_are_both_listed(kube, deps):
    planned(kube, deps)
    twin = copy.deepcopy(kube.fleets[KEY])
    twin["metadata"]["name"] = "night-shift"
    kube.fleets[("warehouse", "night-shift")] = twin
    reconcile_usage(deps)
    name = twin["status"]["placement"][0]["module"]
    status = kube.modules[("warehouse", name)]["status"]
    assert status["fleets"] == ["night-shift", "warehouse"]
    one = sum(e["module"] == name for e in twin["status"]["placement"])
    assert status["instances"] == 2 * one


def test_a_module_shows_its_measured_miss_rate_pooled_over_its_fleets(kube, deps):
    placement = planned(kube, deps)
    name = next(e["module"] for e in placement if e["robot"])
    twin = copy.deepcopy(kube.fleets[KEY])
    twin["metadata"]["name"] = "night-shift"
    twin["status"]["measured"] = [
        {"module": name, "predictedMissRate": 0.0, "measuredMissRate": 0.1, "cycles": 100.0}
    ]
    kube.fleets[("warehouse", "night-shift")] = twin
    reconcile_usage(deps)
    assert kube.modules[("warehouse", name)]["status"]["measuredMissRate"] == 0.1
    # the drift pass's measures of the other fleet, fresher than its status
    deps.store.state(KEY).drift.modules = {name: ModuleDrift(0.0, 0.01, 300.0, None)}
    reconcile_usage(deps)
    status = kube.modules[("warehouse", name)]["status"]
    assert status["measuredMissRate"] == pytest.approx((10 + 3) / 400)
    assert status["measuredMiss"] == "3.2%"
    unmeasured = next(s for (_, n), m in kube.modules.items() if n != name for s in [m["status"]])
    assert "measuredMissRate" not in unmeasured and "measuredMiss" not in unmeasured
    patches = len(kube.module_patches)
    reconcile_usage(deps)
    assert len(kube.module_patches) == patches, "an unchanged rate is not written again"
    deps.store.state(KEY).drift.modules = {}
    twin["status"]["measured"] = []
    reconcile_usage(deps)
    assert "measuredMissRate" not in kube.modules[("warehouse", name)]["status"]
