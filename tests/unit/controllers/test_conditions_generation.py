"""Conditions follow Kubernetes' API conventions: each says the generation it was computed for,
so a status that has not caught up with a spec change is visible as such, and
``kubectl wait --for=condition=Ready`` (which refuses a condition whose observedGeneration is
below metadata.generation: kubectl's pkg/cmd/wait/condition.go) cannot pass on a stale one."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")


def kubectl_wait_passes(obj: dict[str, Any], type_: str = "Ready") -> bool:
    """kubectl wait --for=condition=<type>'s check, as kubectl implements it."""
    generation = obj["metadata"].get("generation")
    status = obj.get("status") or {}
    for cond in status.get("conditions") or []:
        if cond["type"] != type_:
            continue
        observed = cond.get("observedGeneration", status.get("observedGeneration"))
        if generation is not None and observed is not None and observed < generation:
            return False
        return bool(cond["status"] == "True")
    return False


def generations(obj: dict[str, Any]) -> set[int]:
    status = obj["status"]
    return {status["observedGeneration"], *(c["observedGeneration"] for c in status["conditions"])}


@pytest.mark.integration  # two plans: over a second
def test_ready_lags_a_spec_change_until_the_new_generation_is_rolled_out(kube, deps):
    reconcile(kube.get_fleet(*KEY), deps)
    kube.run_pods()
    reconcile(kube.get_fleet(*KEY), deps)
    fleet = kube.fleets[KEY]
    assert kubectl_wait_passes(fleet) and generations(fleet) == {1}

    # a spec change: a spare edge node joins while a used one fails; nothing reconciled yet
    used = sorted(n for n in kube.compute_nodes if n.startswith("edge"))[0]
    spare = copy.deepcopy(kube.compute_nodes[used])
    spare["metadata"] = {"name": "edge-spare", "generation": 1, "uid": "uid-edge-spare"}
    kube.compute_nodes["edge-spare"] = spare
    node = copy.deepcopy(kube.nodes[used])
    node["metadata"]["name"] = "edge-spare"
    kube.nodes["edge-spare"] = node
    fleet["spec"]["nodes"].append("edge-spare")
    fleet["metadata"]["generation"] = 2
    ready = {c["type"]: c for c in fleet["status"]["conditions"]}["Ready"]
    assert ready["status"] == "True" and ready["observedGeneration"] == 1
    assert not kubectl_wait_passes(fleet), "a True Ready of generation 1 does not answer for 2"

    # the reconcile of generation 2: every condition speaks for it; Ready waits for the pods
    kube.set_ready(used, False)
    reconcile(kube.get_fleet(*KEY), deps)
    assert generations(fleet) == {2}
    assert not kubectl_wait_passes(fleet), "modules still move off the failed node"
    kube.run_pods()
    reconcile(kube.get_fleet(*KEY), deps)
    assert generations(fleet) == {2} and kubectl_wait_passes(fleet)


def test_a_held_fleet_says_which_generation_it_holds(kube, deps):
    reconcile(kube.get_fleet(*KEY), deps)
    fleet = kube.fleets[KEY]
    fleet["spec"]["paused"] = True
    fleet["metadata"]["generation"] = 5
    reconcile(kube.get_fleet(*KEY), deps)
    status = fleet["status"]
    assert status["observedGeneration"] == 5
    scheduled = {c["type"]: c for c in status["conditions"]}["Scheduled"]
    assert scheduled["reason"] == "Paused" and scheduled["observedGeneration"] == 5
    assert len({c["type"] for c in status["conditions"]}) == len(status["conditions"])
