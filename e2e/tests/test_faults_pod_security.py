"""Pod Security admission "restricted" (issue 37, item 8): the examples run in namespaces
labelled ``pod-security.kubernetes.io/enforce: restricted`` with a running operator, and every
rendered pod is admitted (all Deployments available, no FailedCreate), discovery servers and
standbys included. The admission plugin is shown to be on: a privileged pod is refused.

    pytest e2e/tests/test_faults_pod_security.py --with-e2e -m faults
"""

from __future__ import annotations

from typing import Any

import pytest

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import Operator, example_docs, wait_ready
from fogfleet.render.ros import COMPONENT_DISCOVERY

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.faults,
    pytest.mark.bed("the bed's real nodes and a running local operator"),
    pytest.mark.timeout(420),
]

ENFORCE = "pod-security.kubernetes.io/enforce"
STANDBY_MODULE = "object-pose-estimation"  # offloaded in single-robot's plan: gets a standby


def _restrict(kube: Kube, namespace: str) -> None:
    kube.kubectl("label", "namespace", namespace, f"{ENFORCE}=restricted", "--overwrite")


def _docs(example: str, namespace: str) -> list[dict[str, Any]]:
    docs = example_docs(example, namespace)
    if example == "single-robot":  # an on-board fallback, so a standby is rendered
        for d in docs:
            if d["kind"] == "SoftwareModule" and d["metadata"]["name"] == STANDBY_MODULE:
                d["spec"]["fallback"] = {"mode": "onboard"}
    return docs


def test_a_privileged_pod_is_refused(kube: Kube, namespace: str) -> None:
    _restrict(kube, namespace)
    pod = ('{"apiVersion":"v1","kind":"Pod","metadata":{"name":"root"},"spec":{"containers":'
           '[{"name":"c","image":"busybox","securityContext":{"privileged":true}}]}}')  # fmt: skip
    proc = kube.kubectl("create", "--dry-run=server", "-n", namespace, "-f", "-",
                        input=pod, check=False)  # fmt: skip
    assert proc.returncode != 0, proc.stdout
    assert "violates PodSecurity" in proc.stderr, proc.stderr


@pytest.mark.parametrize("example", ["warehouse-lite", "single-robot"])
def test_every_rendered_pod_is_admitted(
    kube: Kube, namespace: str, operator: Operator, example: str
) -> None:
    _restrict(kube, namespace)
    docs = _docs(example, namespace)
    kube.apply(docs, namespace=namespace)
    fleet = next(d["metadata"]["name"] for d in docs if d["kind"] == "RobotFleet")
    wait_ready(kube, namespace, fleet, timeout=300)
    deps = kube.kubectl_json("get", "deployments", "-n", namespace)["items"]
    components = {d["metadata"].get("labels", {}).get("app.kubernetes.io/component") for d in deps}
    assert COMPONENT_DISCOVERY in components, "no discovery server"
    if example == "single-robot":
        assert "fallback-standby" in components, components

    def all_available() -> bool:
        items = kube.kubectl_json("get", "deployments", "-n", namespace)["items"]
        return all(
            (d.get("status", {}).get("availableReplicas") or 0) >= (d["spec"].get("replicas") or 0)
            for d in items
        )

    kube.wait_for("every Deployment available", all_available, timeout=240)
    failed = kube.kubectl_json("get", "events", "-n", namespace, "--field-selector",
                               "reason=FailedCreate")["items"]  # fmt: skip
    assert not failed, [e.get("message") for e in failed]
    assert operator.proc is not None and operator.proc.poll() is None, operator.logs()
