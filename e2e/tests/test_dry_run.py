"""What fogfleet writes or refuses, checked by the real API server with a server-side dry run
(nothing is created): the HPA ``fogfleet render`` prints for ``scaling.backend: hpa``, the
objects of a fleet whose name begins with a digit, and the CRD's rule on
``spec.ros.rmwImplementation``. Needs only the bed's API server (``dryrun``).

    pytest e2e/tests/test_dry_run.py --with-e2e -m dryrun
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import EXAMPLES, example_docs, install_crds, of_kind
from fogfleet.commandline.cli import main

pytestmark = [pytest.mark.e2e, pytest.mark.portable, pytest.mark.dryrun, pytest.mark.timeout(180)]

HPA_SCALING = (
    "  scaling:\n    minReplicas: 2\n    maxReplicas: 6\n    backend: hpa\n"
    "    slo: {metric: responseTime, targetMillis: 350, percentile: 99}\n"
    "    behavior: {preset: tinykube}\n"
)


def _dry_run(kube: Kube, docs: list[dict[str, Any]], namespace: str) -> tuple[int, str]:
    """Server-side apply with ``--dry-run=server``: validated and admitted, never stored."""
    for doc in docs:
        doc["metadata"]["namespace"] = namespace
    proc = kube.kubectl(
        "apply",
        "--server-side",
        "--dry-run=server",
        "--field-manager=fogfleet-e2e",
        "-f",
        "-",
        input=json.dumps({"apiVersion": "v1", "kind": "List", "items": docs}),
        check=False,
    )
    return proc.returncode, proc.stdout + proc.stderr


def _rendered_hpa_fleet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> list[Any]:
    """``fogfleet render`` of the shared-detector fleet with its detector on backend hpa."""
    for f in (EXAMPLES / "shared-detector").glob("*.yaml"):  # the folder stands alone
        shutil.copy(f, tmp_path / f.name)
    modules = tmp_path / "modules.yaml"
    text, n = re.subn(r"  scaling:\n(    .*\n)+", HPA_SCALING, modules.read_text(), count=1)
    assert n == 1
    modules.write_text(text)
    code = main(["render", str(tmp_path), "--generations", "5", "--population", "10"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return list(yaml.safe_load_all(out))


def test_the_rendered_hpa_is_valid_for_the_api_server(
    kube: Kube, namespace: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    docs = _rendered_hpa_fleet(tmp_path, capsys)
    (hpa,) = of_kind(docs, "HorizontalPodAutoscaler")
    target = next(
        d for d in of_kind(docs, "Deployment")
        if d["metadata"]["name"] == hpa["spec"]["scaleTargetRef"]["name"]
    )  # fmt: skip
    code, out = _dry_run(kube, [target, hpa], namespace)
    assert code == 0, out
    name = hpa["metadata"]["name"]  # render.names.hpa_name
    assert f"horizontalpodautoscaler.autoscaling/{name} serverside-applied" in out
    # the dry run validates: the same HPA with impossible bounds is refused
    hpa["spec"]["minReplicas"], hpa["spec"]["maxReplicas"] = 3, 2
    code, out = _dry_run(kube, [hpa], namespace)
    assert code != 0 and "maxReplicas" in out, out


def test_a_fleet_whose_name_begins_with_a_digit_renders_objects_the_api_server_takes(
    kube: Kube, namespace: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 45: a Service name is a DNS-1035 label, so fleet ``7-robot``'s discovery Service
    begins with a letter (``render.names``); its Deployments and NetworkPolicies pass too."""
    for f in (EXAMPLES / "single-robot").glob("*.yaml"):  # the folder stands alone
        shutil.copy(f, tmp_path / f.name)
    fleet = tmp_path / "fleet.yaml"
    text, n = re.subn(r"(?m)^  name: single-robot$", "  name: 7-robot", fleet.read_text())
    assert n == 1
    fleet.write_text(text)
    code = main(["render", str(tmp_path), "--generations", "2", "--population", "6", "--seed", "1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    docs = [d for d in yaml.safe_load_all(out) if d]
    assert of_kind(docs, "Service") and of_kind(docs, "NetworkPolicy"), sorted(
        d["kind"] for d in docs
    )
    code, out = _dry_run(kube, docs, namespace)
    assert code == 0, out


def test_the_crd_refuses_an_rmw_the_discovery_servers_cannot_isolate(
    kube: Kube, namespace: str
) -> None:
    install_crds(kube)
    (fleet,) = of_kind(example_docs("warehouse", namespace), "RobotFleet")
    fleet["spec"]["ros"] = {"rmwImplementation": "rmw_cyclonedds_cpp"}
    code, out = _dry_run(kube, [fleet], namespace)
    assert code != 0, out
    assert "rmwImplementation" in out and "rmw_fastrtps_cpp" in out
    fleet["spec"]["ros"] = {"rmwImplementation": "rmw_fastrtps_cpp"}
    code, out = _dry_run(kube, [fleet], namespace)
    assert code == 0, out
    fleet["spec"]["ros"] = {"enabled": False, "rmwImplementation": "rmw_cyclonedds_cpp"}
    code, out = _dry_run(kube, [fleet], namespace)
    assert code == 0, out
