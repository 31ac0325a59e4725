"""kubectl fogfleet on a running fleet (issue 38): ``why`` names the node status.placement
names, and ``top`` shows a measured miss rate for every module whose status measured one.

The plugin runs as users run it, a separate process with the test's kubeconfig
(``python -m fogfleet.commandline.kubectl``, what the ``kubectl-fogfleet`` console script calls).
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    ROOT,
    Operator,
    apply_warehouse,
    fleet,
    wait_ready,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the operator runs as a local process beside the bed"),
    pytest.mark.observability,
    pytest.mark.timeout(420),
]


def _plugin(kube: Kube, namespace: str, *args: str, code: int = 0) -> Any:
    """``kubectl fogfleet ARGS -o json`` against the bed, parsed (its stderr when it exits
    ``code`` > 0); the plugin must not have explained by itself unless told ``--local``."""
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "fogfleet.commandline.kubectl",
            *args,
            "--kubeconfig",
            str(kube.kubeconfig),
            "-n",
            namespace,
            "-o",
            "json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        check=False,
    )
    assert out.returncode == code, out.stderr
    if code:
        return out.stderr
    assert "did not explain" not in out.stderr, out.stderr
    return json.loads(out.stdout)


def test_why_and_top_match_the_fleets_status(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    apply_warehouse(kube, namespace)
    wait_ready(kube, namespace)
    status = fleet(kube, namespace)["status"]
    where = {
        (e.get("robot") or "", e["module"], int(e.get("replica") or 0)): e["node"]
        for e in status["placement"]
    }
    node_of = {
        c["metadata"]["name"]: c["spec"].get("nodeName") or c["metadata"]["name"]
        for c in kube.kubectl_json("get", "computenodes")["items"]
    }
    for module, robot in (("nav-controller", "robot-1"), ("scene-segmentation", "robot-2")):
        doc = _plugin(kube, namespace, "why", "warehouse", module, "--robot", robot)
        (inst,) = doc["instances"]
        # the plugin names ComputeNodes, status.placement their Kubernetes Nodes
        assert node_of.get(inst["node"], inst["node"]) == where[(robot, module, 0)]
        assert doc["predictedMissRate"] is not None
        assert inst["alternatives"], "every node it could have used is explained"
        if module == "nav-controller":
            edges = [a for a in inst["alternatives"] if a["tier"] == "edge"]
            assert edges and {a["rule"] for a in edges} == {"taxonomy"}
        # the operator answered from the plan it holds: the plugin's own computation agrees
        local = _plugin(kube, namespace, "why", "warehouse", module, "--robot", robot, "--local")
        assert {**doc, "measuredMissRate": None} == {**local, "measuredMissRate": None}
    said = _plugin(kube, namespace, "why", "warehouse", "no-such-module", code=2)
    assert "no instance of module no-such-module" in said and "did not explain" not in said
    left = kube.kubectl_json("get", "explanationrequests", "-n", namespace)["items"]
    assert not left, "the plugin deletes each request it made"

    # the bounded read of a large fleet (issue 46), against the real API server: the
    # Deployments' metadata name their node, and the fleet's own Pods are left out
    from fogfleet.commandline.kubectl.cluster import connect

    source, _ = connect(str(kube.kubeconfig), None)
    meta = source.list_deployment_metadata(namespace, {"fogfleet.io/fleet": "warehouse"})
    named = {
        (a.get("fogfleet.io/robot", ""), a["fogfleet.io/module"], int(a["fogfleet.io/replica"])): (
            a["fogfleet.io/node"]
        )
        for a in (d["metadata"]["annotations"] for d in meta)
        if "fogfleet.io/module" in a and a.get("fogfleet.io/role") != "standby"
    }
    assert meta and all("spec" not in d for d in meta)
    assert named == where
    mine = [
        p
        for p in source.list_node_load(besides=(namespace, "warehouse"))
        if p["metadata"]["namespace"] == namespace
        and p["metadata"]["labels"].get("fogfleet.io/fleet") == "warehouse"
    ]
    assert not mine and any(
        p["metadata"]["namespace"] == namespace for p in source.list_node_load()
    )

    top = _plugin(kube, namespace, "top", "warehouse")
    assert top["split"] == status.get("split")
    raw = kube.kubectl_json("get", "softwaremodules", "-n", namespace)
    observed = {
        m["metadata"]["name"]
        for m in raw["items"]
        if any(
            r.get("cycles") and r.get("missedPercent") is not None
            for r in (m.get("status") or {}).get("observed") or []
        )
    }
    observed |= {
        m["module"] for m in status.get("measured") or [] if m.get("measuredMissRate") is not None
    }
    for m in top["modules"]:
        assert m["predictedMissRate"] is not None
        if m["module"] in observed:
            assert m["measuredMissRate"] is not None, m
