"""The pod-template subset of a SoftwareModule: validated with the field named, merged with
what fogfleet owns, restricted security defaults wherever the user says nothing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.build import build_problem
from fogfleet.render.deployments import render_fleet
from fogfleet.render.ros import PLANNED_TOLERATION, ROBOT_TOLERATIONS

EXAMPLES = Path(__file__).resolve().parents[3] / "manifests" / "examples"

TEMPLATE: dict[str, Any] = yaml.safe_load((EXAMPLES / "pod-template" / "module.yaml").read_text())[
    "spec"
]["template"]


def module_with(template: dict[str, Any]) -> SoftwareModule:
    catalog = load_paths([EXAMPLES / "warehouse"])
    (_, _), module = next(iter(catalog.modules.items()))
    body = module.model_dump(by_alias=True, exclude_none=True, mode="json")
    body["spec"]["template"] = template
    return SoftwareModule.model_validate(body)


def rendered_pod(template: dict[str, Any]) -> dict[str, Any]:
    catalog = load_paths([EXAMPLES / "warehouse"])
    key = next(iter(catalog.modules))
    catalog.modules[key] = module_with(template)
    problem = build_problem(catalog.fleets[0], catalog)
    placement = [int(np.flatnonzero(row)[0]) for row in problem.allowed]
    mods = {name: m for (_, name), m in catalog.modules.items()}
    deps = render_fleet(problem, mods, np.array(placement))
    mine = [d for d in deps if d["metadata"]["annotations"]["fogfleet.io/module"] == key[1]]
    return mine[0]["spec"]["template"]


def test_the_users_pod_fields_reach_the_pod_beside_fogfleets(tmp_path: Path) -> None:
    pod = rendered_pod(TEMPLATE)
    spec = pod["spec"]
    main, probe = spec["containers"]
    assert [v["name"] for v in spec["volumes"]] == ["tmp", "params", "camera", "maps"]
    assert spec["volumes"][2]["hostPath"] == {"path": "/dev/video0", "type": "CharDevice"}
    assert [m["mountPath"] for m in main["volumeMounts"]] == [
        "/tmp",
        "/params",
        "/dev/video0",
        "/maps",
    ]
    env = {e["name"]: e for e in main["env"]}
    assert env["MODEL"]["value"] == "yolo"
    assert env["TOKEN"] == {
        "name": "TOKEN",
        "valueFrom": {"secretKeyRef": {"name": "api", "key": "token"}},
    }
    assert env["FOGFLEET_MODULE"]["value"] == pod["metadata"]["annotations"]["fogfleet.io/module"]
    assert main["envFrom"] == [{"configMapRef": {"name": "detector-params"}}]
    assert [p["name"] for p in main["ports"]] == ["grpc"]  # the module serves no metrics
    assert main["readinessProbe"] == {"tcpSocket": {"port": "grpc"}, "periodSeconds": 5}
    assert "livenessProbe" not in main
    assert probe["livenessProbe"]["httpGet"] == {"path": "/healthz", "port": "m-cycle-probe"}
    assert main["resources"]["limits"]["squat.ai/video"] == "1"
    assert main["resources"]["requests"]["squat.ai/video"] == "1"
    cpu = main["resources"]["requests"]["cpu"], main["resources"]["limits"]["cpu"]
    assert 2 * parse_cpu(cpu[0]) == pytest.approx(parse_cpu(cpu[1])), cpu  # default headroom
    assert main["securityContext"]["capabilities"] == {"drop": ["ALL"], "add": ["SYS_NICE"]}
    assert main["securityContext"]["allowPrivilegeEscalation"] is False
    assert spec["securityContext"]["supplementalGroups"] == [44]
    assert spec["tolerations"][0]["operator"] == "Exists"
    assert spec["imagePullSecrets"] == [{"name": "ghcr"}]
    assert spec["serviceAccountName"] == "detector"
    assert spec["automountServiceAccountToken"] is False
    assert spec["affinity"]["nodeAffinity"]  # placement stays fogfleet's
    assert probe["name"] == "cycle-probe" and probe["args"] == ["probe", "--port", "9101"]
    assert probe["ports"][0]["containerPort"] == 9101
    assert probe["resources"]["limits"] == {"cpu": "50m", "memory": "128Mi"}
    assert {e["name"] for e in probe["env"]} >= {e["name"] for e in main["env"]} - {
        "MODEL",
        "TOKEN",
    }
    assert pod["metadata"]["annotations"]["prometheus.io/port"] == "9101"  # the probe


def test_a_module_that_says_nothing_gets_the_restricted_defaults() -> None:
    spec = rendered_pod({"image": "ghcr.io/acme/m:1"})["spec"]
    (main,) = spec["containers"]
    sc = main["securityContext"]
    assert sc["runAsNonRoot"] is True and sc["allowPrivilegeEscalation"] is False
    assert sc["readOnlyRootFilesystem"] is True and sc["capabilities"] == {"drop": ["ALL"]}
    assert sc["seccompProfile"] == {"type": "RuntimeDefault"}
    assert spec["automountServiceAccountToken"] is False
    assert "imagePullSecrets" not in spec
    # placed on a robot: the taint of nodes kept for planned pods, and the tolerations that keep
    # it there while the robot is cut off
    assert spec["tolerations"] == [PLANNED_TOLERATION, *map(dict, ROBOT_TOLERATIONS)]
    assert "livenessProbe" not in main  # no metricsPort: nothing to probe


def test_the_probe_sidecar_is_scraped_when_the_module_serves_no_metrics() -> None:
    tpl = {"image": "ghcr.io/acme/m:1", "sidecars": TEMPLATE["sidecars"]}
    pod = rendered_pod(tpl)
    assert pod["metadata"]["annotations"]["prometheus.io/port"] == "9101"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"affinity": {}}, "affinity: set by fogfleet (the pod's placement is the plan's"),
        ({"nodeSelector": {"a": "b"}}, "nodeSelector: set by fogfleet"),
        ({"resources": {}}, "resources: set by fogfleet (CPU comes from the plan"),
        ({"volumeMounts": [{"name": "nope", "mountPath": "/x"}]}, "volume nope is not in volumes"),
        ({"volumes": [{"name": "v"}]}, "v: set exactly one of configMap, secret, emptyDir"),
        ({"volumes": [{"name": "tmp", "emptyDir": {}}]}, "name: tmp is fogfleet's"),
        ({"readinessProbe": {"periodSeconds": 3}}, "set exactly one of exec, httpGet, tcpSocket"),
        ({"readinessProbe": {"tcpSocket": {"port": "Bad_Name"}}}, "is not a port name"),
        (
            {"env": [{"name": "X", "value": "1", "valueFrom": {"fieldRef": {"fieldPath": "a"}}}]},
            "X: set value or valueFrom, not both",
        ),
        (
            {"sidecars": [{"name": "s", "image": "i", "env": [{"name": "ROS_DOMAIN_ID"}]}]},
            "sidecars[0].env[0].name: ROS_DOMAIN_ID is set by fogfleet",
        ),
        (
            {"ports": [{"name": "metrics", "containerPort": 1}], "metricsPort": 2},
            "the name metrics is fogfleet's",
        ),
        (
            {"ports": [{"containerPort": 9100}], "metricsPort": 9100},
            "ports: 9100 listed more than once",
        ),
        ({"securityContext": {"runAsUser": 0}}, "runAsUser: 0 is root; set runAsNonRoot: false"),
    ],
)
def test_bad_templates_are_refused_naming_the_field(change: dict[str, Any], expected: str) -> None:
    with pytest.raises(ValidationError) as err:
        module_with({"image": "ghcr.io/acme/m:1", **change})
    assert expected in str(err.value)
