"""Invalid input on the local control plane: what the real kube-apiserver refuses by the CRDs'
schemas (an unknown tier, a negative cycle time, no profile, a pod-template field fogfleet
owns, a probe port out of range, a robot listed twice), what it stores as users write it (the
pod-template subset), and what the operator reports without touching what runs (a dangling
module reference, a fleet that cannot fit).

Each test runs its own `fogfleet run` process scoped to the test's namespace.
"""

from __future__ import annotations

from typing import Any

import pytest
import yaml

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    ROOT,
    Operator,
    add_module_to_fleet,
    apply_warehouse,
    condition_is,
    conditions,
    deployment_versions,
    dump,
    events,
    example_docs,
    fleet,
    of_kind,
    wait_ready,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's kwok warehouse nodes and the operator run as a host process"),
    pytest.mark.timeout(420),
]

FULL_TEMPLATE: dict[str, Any] = yaml.safe_load(
    (ROOT / "manifests" / "examples" / "pod-template" / "module.yaml").read_text()
)["spec"]["template"]


def test_invalid_objects_are_rejected_or_reported_without_touching_what_runs(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    docs = example_docs("warehouse", namespace)
    bad_tier = {**of_kind(docs, "ComputeNode")[0], "metadata": {"name": "e2e-bad-tier"}}
    bad_tier["spec"] = {**bad_tier["spec"], "tier": "moon"}
    proc = kube.kubectl("apply", "-f", "-", input=dump(bad_tier), check=False)
    assert proc.returncode != 0 and "tier" in proc.stderr, proc.stderr
    module = dict(of_kind(docs, "SoftwareModule")[0])
    module["spec"] = {**module["spec"], "cycleTimeMillis": -5}
    proc = kube.kubectl("apply", "-f", "-", input=dump(module), check=False)
    assert proc.returncode != 0 and "cycleTimeMillis" in proc.stderr, proc.stderr
    # no profile at all is refused, unless the operator is to profile the module itself
    unprofiled = dict(of_kind(docs, "SoftwareModule")[0])
    unprofiled["spec"] = {**unprofiled["spec"], "profile": []}
    proc = kube.kubectl("apply", "-f", "-", input=dump(unprofiled), check=False)
    assert proc.returncode != 0, proc.stdout
    assert "profile: at least one row, unless profiling.mode is auto" in proc.stderr, proc.stderr
    # a pod-template field fogfleet owns: refused by the API server with the reason
    owned = dict(of_kind(docs, "SoftwareModule")[0])
    owned["spec"] = {**owned["spec"], "template": {**owned["spec"]["template"], "affinity": {}}}
    proc = kube.kubectl("apply", "-f", "-", input=dump(owned), check=False)
    assert proc.returncode != 0, proc.stdout
    assert "affinity: set by fogfleet (the pod's placement is the plan's" in proc.stderr, (
        proc.stderr
    )
    # the pod-template subset users set is accepted as it is written in a Deployment
    full = dict(of_kind(docs, "SoftwareModule")[0])
    full["metadata"] = {"name": "e2e-full-template", "namespace": namespace}
    full["spec"] = {**full["spec"], "template": FULL_TEMPLATE}
    kube.apply(full)
    stored = kube.kubectl_json("get", "softwaremodule", "e2e-full-template", "-n", namespace)
    assert stored["spec"]["template"] == FULL_TEMPLATE  # nothing pruned by the schema
    bad_volume = {**full, "metadata": {"name": "e2e-bad-volume", "namespace": namespace}}
    bad_volume["spec"] = {
        **full["spec"],
        "template": {**FULL_TEMPLATE, "readinessProbe": {"tcpSocket": {"port": 70000}}},
    }
    proc = kube.kubectl("apply", "-f", "-", input=dump(bad_volume), check=False)
    assert proc.returncode != 0 and "readinessProbe" in proc.stderr, proc.stderr
    kube.kubectl("delete", "softwaremodule", "e2e-full-template", "-n", namespace)
    # a robot listed twice would double every module of it: the API server refuses it
    twice = dict(of_kind(docs, "RobotFleet")[0])
    twice["metadata"] = {"name": "e2e-twice", "namespace": namespace}
    twice["spec"] = {**twice["spec"], "robots": ["robot-1", "robot-1"]}
    proc = kube.kubectl("apply", "-f", "-", input=dump(twice), check=False)
    assert proc.returncode != 0 and "spec.robots[1]: Duplicate value" in proc.stderr, proc.stderr

    apply_warehouse(kube, namespace)
    wait_ready(kube, namespace)
    before = deployment_versions(kube, namespace)

    # a dangling reference: Ready=False naming the field, an Event, nothing touched
    add_module_to_fleet(kube, namespace, "no-such-module")
    kube.wait_for(
        "DanglingReference",
        lambda: condition_is(kube, namespace, "Ready", "False", reason="DanglingReference"),
        60,
    )
    msg = conditions(fleet(kube, namespace))["Ready"]["message"]
    assert "spec.modules[8].name" in msg and "no-such-module" in msg, msg
    assert events(kube, namespace, "DanglingReference")
    after = deployment_versions(kube, namespace)
    assert after == before

    # the module appears: the fleet re-plans by itself
    extra = dict(of_kind(docs, "SoftwareModule")[3])
    extra["metadata"] = {"name": "no-such-module", "namespace": namespace}
    kube.apply(extra)
    kube.wait_for(
        "Ready again with 45 modules",
        lambda: (
            condition_is(kube, namespace, "Ready", "True")
            and fleet(kube, namespace)["status"]["modulesTotal"] == 45
        ),
        120,
        interval=1,
    )

    # a fleet that cannot fit: every robot module asks for 64 GiB
    greedy = of_kind(docs, "SoftwareModule")[2]  # nav-controller: stays on board
    greedy = {**greedy, "metadata": {"name": "memory-hog", "namespace": namespace}}
    greedy["spec"] = {**greedy["spec"], "resources": {"cpu": "500m", "memory": "64Gi"}}
    kube.apply(greedy)
    before = deployment_versions(kube, namespace)
    add_module_to_fleet(kube, namespace, "memory-hog")
    kube.wait_for(
        "Infeasible",
        lambda: condition_is(kube, namespace, "Ready", "False", reason="Infeasible"),
        120,
    )
    assert events(kube, namespace, "PlanFailed")
    msg = conditions(fleet(kube, namespace))["Ready"]["message"]
    assert "memory" in msg, msg
    after = deployment_versions(kube, namespace)
    assert after == before
