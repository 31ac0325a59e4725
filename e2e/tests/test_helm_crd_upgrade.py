"""CRD upgrades through Helm (issue 38): the chart templates its CRDs (``crds.install``, kept on
uninstall), so ``helm upgrade`` brings a changed schema, which a chart's ``crds/`` folder never
does.

Install the chart (taking over the bed's CRDs, applied from crds/ as every e2e test has them),
bring the warehouse fleet Ready, then ``helm upgrade`` to a copy of the chart whose RobotFleet
CRD gained a spec field. The field is shown accepted by the API server: a server-side dry run
of the fleet with the field set is refused before the upgrade (kubectl's strict field
validation: unknown field) and accepted after it, the field kept in what the API server
returns. The dry run changes nothing: the running operator, which does not know the field,
would refuse a fleet that carried it. Nothing running is disturbed (same operator pods, same
Deployments and pods by uid, the fleet Ready at the same generation), and ``helm uninstall``
keeps the CRDs and the fleet. Finally the bed's CRDs are put back as generated.
"""

from __future__ import annotations

import json
import secrets
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    CHART,
    OPERATOR_LABELS,
    ROOT,
    apply_warehouse,
    example_docs,
    fleet,
    helm,
    install_crds,
    of_kind,
    wait_ready,
)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's helm and its CRDs, restored after the upgrade"),
    pytest.mark.real,
    pytest.mark.incluster,
    pytest.mark.observability,
    pytest.mark.timeout(600),
]

RELEASE = "fogfleet-crdup"
SYSTEM = "fogfleet-crdup-system"
CRD_FILE = "robotfleets.fogfleet.io.yaml"
NEW_FIELD = "e2eNote"


def chart_with_new_field(tmp: Path) -> Path:
    """A copy of the chart whose RobotFleet CRD template has one more spec property."""
    chart = tmp / "fogfleet"
    shutil.copytree(CHART, chart)
    path = chart / "templates" / "crds" / CRD_FILE
    lines = path.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("{{- if"))
    tail = max(i for i, line in enumerate(lines) if line.startswith("{{- end"))
    crd = yaml.safe_load("\n".join(lines[head + 1 : tail]))
    spec = crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["spec"]
    spec["properties"][NEW_FIELD] = {"type": "string", "description": "Added by an upgrade."}
    body = yaml.safe_dump(crd, sort_keys=True, default_flow_style=False, width=100)
    path.write_text("\n".join(lines[: head + 1]) + "\n" + body + "\n".join(lines[tail:]) + "\n")
    return chart


def dry_run_fleet_with_field(kube: Kube, ns: str) -> subprocess.CompletedProcess[str]:
    body = of_kind(example_docs("warehouse", ns), "RobotFleet")[0]
    body["spec"][NEW_FIELD] = "hello"
    return kube.kubectl(
        "apply", "--server-side", "--dry-run=server", "--field-manager=e2e-crd-upgrade",
        "-o", "json", "-f", "-", input=json.dumps(body), check=False,
    )  # fmt: skip


def running(kube: Kube, ns: str) -> dict[str, Any]:
    """What must not change: the fleet's Deployments and pods by uid, and the operator pods."""

    def uids(kind: str, namespace: str, *selector: str) -> dict[str, str]:
        items = kube.kubectl_json("get", kind, "-n", namespace, *selector)["items"]
        return {i["metadata"]["name"]: i["metadata"]["uid"] for i in items}

    return {
        "deployments": uids("deployments", ns),
        "pods": uids("pods", ns),
        "operator": uids("pods", SYSTEM, "-l", OPERATOR_LABELS),
    }


@pytest.fixture
def released(kube: Kube, cluster: Cluster) -> Iterator[str]:
    install_crds(kube)
    ns = f"e2e-crdup-{secrets.token_hex(3)}"
    kube.apply({"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": ns}})
    helm(
        "install", RELEASE, str(CHART), "-n", SYSTEM, "--create-namespace",
        "--set", f"watchNamespaces={{{ns}}}",
        "--set-string", "nodeSelector.fogfleet\\.io/e2e-real=true",
        "--set", "logFormat=plain", "--set", "replicaCount=1",
        "--set", "crds.install=true",
        "--take-ownership",  # the bed's CRDs, applied from crds/ before any chart
        "--wait", "--timeout", "240s",
    )  # fmt: skip
    try:
        yield ns
    finally:
        if RELEASE in helm("list", "-n", SYSTEM, "-q").split():
            helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
        kube.kubectl("delete", "namespace", ns, "--wait=false", "--ignore-not-found", check=False)
        kube.kubectl("delete", "namespace", SYSTEM, "--wait=false", "--ignore-not-found",
                     check=False)  # fmt: skip
        # the bed's CRDs as generated again (no upgraded field, no release's annotations)
        kube.kubectl("replace", "-f", str(ROOT / "crds" / CRD_FILE), check=False)
        install_crds(kube)


def test_helm_upgrade_brings_a_new_crd_field_and_uninstall_keeps_crds_and_fleets(
    kube: Kube, released: str, tmp_path: Path
) -> None:
    ns = released
    crd = kube.kubectl_json("get", "crd", "robotfleets.fogfleet.io")
    assert crd["metadata"]["annotations"]["helm.sh/resource-policy"] == "keep"
    assert crd["metadata"]["annotations"]["meta.helm.sh/release-name"] == RELEASE
    apply_warehouse(kube, ns)
    wait_ready(kube, ns, timeout=300)
    generation = fleet(kube, ns)["metadata"]["generation"]
    before = running(kube, ns)
    assert before["deployments"] and before["pods"] and before["operator"]

    refused = dry_run_fleet_with_field(kube, ns)
    assert refused.returncode != 0 and NEW_FIELD in refused.stderr, refused.stderr

    helm(
        "upgrade", RELEASE, str(chart_with_new_field(tmp_path)), "-n", SYSTEM, "--reuse-values",
        "--wait", "--timeout", "240s",
    )  # fmt: skip
    schema = kube.kubectl_json("get", "crd", "robotfleets.fogfleet.io")["spec"]["versions"][0]
    spec = schema["schema"]["openAPIV3Schema"]["properties"]["spec"]["properties"]
    assert NEW_FIELD in spec, "helm upgrade did not bring the CRD's new field"
    kube.wait_for(
        "the API server serving the new schema",
        lambda: dry_run_fleet_with_field(kube, ns).returncode == 0,
        60,
    )
    accepted = json.loads(dry_run_fleet_with_field(kube, ns).stdout)
    assert accepted["spec"][NEW_FIELD] == "hello", "the field was pruned"

    wait_ready(kube, ns, timeout=60)
    assert fleet(kube, ns)["metadata"]["generation"] == generation
    assert running(kube, ns) == before, "the upgrade disturbed what runs"

    helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
    for name in ("robotfleets", "softwaremodules", "computenodes"):
        kube.kubectl("get", "crd", f"{name}.fogfleet.io")  # kept
    kept = fleet(kube, ns)
    assert kept["metadata"]["uid"] and kept["metadata"]["generation"] == generation
    assert running(kube, ns)["deployments"] == before["deployments"]
