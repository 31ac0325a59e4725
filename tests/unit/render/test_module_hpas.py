"""``scaling.backend: hpa``: an autoscaling/v2 HPA on a shared module's first placed replica,
with the module's bounds less its other planned replicas, in ``fogfleet render``."""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.labels import ANNOTATION_MODULE, ANNOTATION_REPLICA, ANNOTATION_ROBOT
from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.commandline.cli import main
from fogfleet.render.names import hpa_name
from fogfleet.render.scaling import SLO_METRIC, module_hpas

REPO = Path(__file__).resolve().parents[3]
EXAMPLES = REPO / "manifests" / "examples"
HPA_SCALING = (
    "  scaling:\n    minReplicas: 2\n    maxReplicas: 6\n    backend: hpa\n"
    "    slo: {metric: responseTime, targetMillis: 350, percentile: 99}\n"
    "    behavior: {preset: tinykube}\n"
)


def _detector(scaling: dict[str, Any]) -> SoftwareModule:
    docs = yaml.safe_load_all((EXAMPLES / "shared-detector" / "modules.yaml").read_text())
    doc = next(d for d in docs if d["metadata"]["name"] == "object-detector")
    doc["spec"]["scaling"] = scaling
    module = parse_object(doc)
    assert isinstance(module, SoftwareModule)
    return module


def _dep(name: str, module: str, replica: int, robot: str = "") -> dict[str, Any]:
    ann = {ANNOTATION_MODULE: module, ANNOTATION_REPLICA: str(replica), ANNOTATION_ROBOT: robot}
    return {"metadata": {"name": name, "annotations": ann}, "spec": {"replicas": 1}}


def test_the_hpa_scales_the_first_replica_within_the_module_bounds() -> None:
    module = _detector(
        {"minReplicas": 3, "maxReplicas": 8, "backend": "hpa", "targetCpuUtilizationPercent": 70}
    )
    deps = [
        _dep("r2", "object-detector", 2),
        _dep("r0", "object-detector", 0),
        _dep("r1", "object-detector", 1),
        _dep("cam", "camera-driver", 0, robot="robot-1"),
    ]
    (item,) = module_hpas(deps, {"object-detector": module}, "ns", "fleet")
    assert (item.module, item.target, item.fixed) == ("object-detector", "r0", 2)
    hpa = item.hpa
    assert (hpa["apiVersion"], hpa["kind"]) == ("autoscaling/v2", "HorizontalPodAutoscaler")
    assert hpa["metadata"]["namespace"] == "ns"
    spec = hpa["spec"]
    assert spec["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment", "name": "r0"}
    # 3..8 for the module: the 2 fixed replicas plus 1..6 of the scaled one
    assert (spec["minReplicas"], spec["maxReplicas"]) == (1, 6)
    assert spec["metrics"][0]["resource"]["target"]["averageUtilization"] == 70
    assert set(spec["behavior"]) == {"scaleUp", "scaleDown"}


def test_other_backends_and_unplaced_modules_get_no_hpa() -> None:
    deps = [_dep("r0", "object-detector", 0)]
    own = _detector({"maxReplicas": 4})
    assert module_hpas(deps, {"object-detector": own}, "ns", "fleet") == []
    hpa = _detector({"maxReplicas": 4, "backend": "hpa", "targetCpuUtilizationPercent": 50})
    assert module_hpas([], {"object-detector": hpa}, "ns", "fleet") == []


@pytest.fixture
def hpa_fleet(tmp_path: Path) -> Path:
    """The shared-detector fleet (its folder stands alone), its detector on backend hpa."""
    for f in (EXAMPLES / "shared-detector").glob("*.yaml"):
        shutil.copy(f, tmp_path / f.name)
    modules = tmp_path / "modules.yaml"
    text, n = re.subn(r"  scaling:\n(    .*\n)+", HPA_SCALING, modules.read_text(), count=1)
    assert n == 1
    modules.write_text(text)
    return tmp_path


def test_render_prints_the_slo_hpa_and_says_so(
    hpa_fleet: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["render", str(hpa_fleet), "--generations", "5", "--population", "10"])
    out, err = capsys.readouterr()
    assert code == 0, err
    docs = list(yaml.safe_load_all(out))
    (hpa,) = [d for d in docs if d["kind"] == "HorizontalPodAutoscaler"]
    replicas = {
        d["metadata"]["name"]: d
        for d in docs
        if d["kind"] == "Deployment"
        and d["metadata"].get("annotations", {}).get(ANNOTATION_MODULE) == "object-detector"
    }
    target = replicas[hpa["spec"]["scaleTargetRef"]["name"]]
    assert target["metadata"]["annotations"][ANNOTATION_REPLICA] == "0"
    assert "replicas" not in target["spec"]  # the HPA owns the count; a re-apply keeps it
    others = len(replicas) - 1
    assert hpa["spec"]["minReplicas"] == max(2 - others, 1)
    assert hpa["spec"]["maxReplicas"] == 6 - others
    (metric,) = hpa["spec"]["metrics"]
    assert metric["type"] == "External"
    assert metric["external"]["metric"]["name"] == SLO_METRIC
    assert metric["external"]["metric"]["selector"]["matchLabels"]["module"] == "object-detector"
    assert metric["external"]["target"] == {"type": "Value", "value": "350m"}
    assert hpa["metadata"]["name"] == hpa_name("detector-fleet", "object-detector")
    assert f"HorizontalPodAutoscaler {hpa['metadata']['name']} scales" in err
    assert "does not apply it" in err
