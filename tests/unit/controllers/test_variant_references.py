"""A fleet whose module falls back to a variant: the variant is a reference of the fleet."""

from __future__ import annotations

import copy
from typing import Any

from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")
HPE, LITE = "human-pose-estimation", "human-pose-lite"


def _with_variant(kube: Any) -> None:
    hpe = kube.modules[("warehouse", HPE)]
    lite = copy.deepcopy(hpe)
    lite["metadata"] = {"name": LITE, "namespace": "warehouse", "generation": 1, "uid": "u-lite"}
    lite["spec"]["template"]["image"] = "example.org/hpe-lite:1"
    lite["spec"]["cycleTimeMillis"] = 200
    lite["spec"]["profile"] = [
        {"hardwareType": "default", "cpu": "500m", "meanMillis": 100, "stdMillis": 10}
    ]
    lite["spec"].pop("fallback", None)
    kube.add(lite)
    hpe["spec"]["fallback"] = {"mode": "variant", "variant": LITE}


def test_the_variant_is_a_reference_and_its_standby_runs_its_image(kube, deps) -> None:
    _with_variant(kube)
    reconcile(kube.get_fleet(*KEY), deps)
    assert KEY in deps.store.using_module("warehouse", LITE)
    standbys = [
        d
        for d in kube.deployments.values()
        if d["metadata"]["annotations"].get("fogfleet.io/role") == "standby"
    ]
    placed = {(p["robot"], p["module"]): p["node"] for p in kube.fleets[KEY]["status"]["placement"]}
    offloaded = [r for (r, m), n in placed.items() if m == HPE and n != r]
    assert len(standbys) == len(offloaded) > 0
    for d in standbys:
        (c,) = d["spec"]["template"]["spec"]["containers"]
        assert c["image"] == "example.org/hpe-lite:1"


def test_a_missing_variant_is_reported_and_becomes_a_reference(kube, deps) -> None:
    _with_variant(kube)
    del kube.modules[("warehouse", LITE)]
    try:
        reconcile(kube.get_fleet(*KEY), deps)
    except Exception as exc:  # the handler maps it; the status says it
        assert "human-pose-lite does not exist" in str(exc)
    ready = next(c for c in kube.fleets[KEY]["status"]["conditions"] if c["type"] == "Ready")
    assert ready["status"] == "False" and "spec.fallback.variant" in ready["message"]
    # creating it later re-plans the fleet (the runtime asks the reference index)
    assert KEY in deps.store.using_module("warehouse", LITE)
