"""Install artifacts: plain manifests, the Helm chart and the Dockerfile keep their promises.

Security settings of the operator pod, least-privilege RBAC (no wildcard, exactly the
resources the operator uses), the chart's values schema, the chart rendering the same RBAC as
manifests/install (with ``helm template``, when a helm binary exists), and a Dockerfile on a
pinned Python with a non-root user.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
INSTALL = REPO / "manifests" / "install"
CHART = REPO / "charts" / "fogfleet"
IMAGE = "ghcr.io/fogfleet/fogfleet:0.1.0"

EXPECTED_RULES = {
    ("fogfleet.io", "robotfleets"): {"get", "list", "watch", "patch"},
    ("fogfleet.io", "softwaremodules"): {"get", "list", "watch", "patch"},
    ("fogfleet.io", "computenodes"): {"get", "list", "watch", "patch"},
    ("fogfleet.io", "robotfleets/status"): {"get", "patch"},
    ("fogfleet.io", "softwaremodules/status"): {"get", "patch"},
    ("fogfleet.io", "computenodes/status"): {"get", "patch"},
    ("fogfleet.io", "explanationrequests"): {"get", "list", "watch", "delete"},
    ("fogfleet.io", "explanationrequests/status"): {"patch"},
    ("", "nodes"): {"get", "list", "watch"},
    ("", "pods"): {"get", "list", "watch"},
    ("apps", "deployments"): {"get", "list", "watch", "create", "patch", "update", "delete"},
    ("batch", "jobs"): {"get", "list", "create", "delete"},
    ("", "services"): {"get", "list", "watch", "create", "patch", "delete"},
    ("networking.k8s.io", "networkpolicies"): {"get", "list", "watch", "create", "patch", "delete"},
    ("", "events"): {"create", "patch"},
    ("events.k8s.io", "events"): {"create", "patch"},
    ("", "namespaces"): {"get", "list", "watch"},
    ("apiextensions.k8s.io", "customresourcedefinitions"): {"get", "list", "watch"},
}


# who may ask the operator why: aggregated into the built-in edit and admin roles
ASKERS = "fogfleet-operator-askers"
ASKER_RULES = {("fogfleet.io", "explanationrequests"): {"create", "get", "list", "watch", "delete"}}


def _install_objects() -> dict[str, dict[str, Any]]:
    """The install's objects by kind; the askers' ClusterRole as ``ClusterRole/<name>``."""
    objs: dict[str, dict[str, Any]] = {}
    for path in sorted(INSTALL.glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if doc:
                name = doc["metadata"]["name"]
                objs[f"ClusterRole/{name}" if name == ASKERS else doc["kind"]] = doc
    return objs


def _grants(rules: list[dict[str, Any]]) -> dict[tuple[str, str], set[str]]:
    out: dict[tuple[str, str], set[str]] = {}
    for rule in rules:
        for group in rule["apiGroups"]:
            for resource in rule["resources"]:
                out.setdefault((group, resource), set()).update(rule["verbs"])
    return out


def _assert_no_wildcards(rules: list[dict[str, Any]]) -> None:
    for rule in rules:
        for key in ("apiGroups", "resources", "verbs"):
            assert "*" not in rule[key], rule
        assert "resourceNames" not in rule and "nonResourceURLs" not in rule, rule
        for verb in rule["verbs"]:
            assert verb not in ("escalate", "bind", "impersonate", "deletecollection"), rule


def _assert_secure_pod(pod: dict[str, Any]) -> None:
    psc = pod["securityContext"]
    assert psc["runAsNonRoot"] is True
    assert psc["runAsUser"] == 65532
    assert psc["seccompProfile"] == {"type": "RuntimeDefault"}
    (container,) = pod["containers"]
    sc = container["securityContext"]
    assert sc["allowPrivilegeEscalation"] is False
    assert sc["readOnlyRootFilesystem"] is True
    assert sc["runAsNonRoot"] is True
    assert sc["capabilities"] == {"drop": ["ALL"]}
    assert sc["seccompProfile"] == {"type": "RuntimeDefault"}
    assert "privileged" not in sc or sc["privileged"] is False
    res = container["resources"]
    assert set(res["requests"]) == {"cpu", "memory"} and set(res["limits"]) == {"cpu", "memory"}
    assert container["image"] == IMAGE
    assert [*container.get("command", []), *container["args"]] == ["fogfleet", "run"]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    assert ports == {"healthz": 8080, "metrics": 9100}
    for probe in ("livenessProbe", "readinessProbe"):
        assert container[probe]["httpGet"] == {"path": "/healthz", "port": "healthz"}
    mounts = {m["mountPath"]: m["name"] for m in container["volumeMounts"]}
    assert mounts == {"/tmp": "tmp"}
    (volume,) = pod["volumes"]
    assert volume["name"] == "tmp" and "emptyDir" in volume
    assert not pod.get("hostNetwork") and not pod.get("hostPID")
    env = {e["name"]: e.get("value") for e in container["env"]}
    assert env["FOGFLEET_LIVENESS_HOST"] == env["FOGFLEET_METRICS_HOST"] == "0.0.0.0"
    assert env["FOGFLEET_STANDALONE"] == "true"


# --- manifests/install ------------------------------------------------------------------


def test_install_has_namespace_account_rbac_and_operator() -> None:
    objs = _install_objects()
    assert set(objs) == {
        "Namespace", "ServiceAccount", "ClusterRole", "ClusterRoleBinding", "Deployment",
        "Role", "RoleBinding", "NetworkPolicy", f"ClusterRole/{ASKERS}",
    }  # fmt: skip
    assert objs["Namespace"]["metadata"]["name"] == "fogfleet-system"
    assert (
        objs["Namespace"]["metadata"]["labels"]["pod-security.kubernetes.io/enforce"]
        == "restricted"
    )
    for kind in ("ServiceAccount", "Deployment", "Role", "RoleBinding", "NetworkPolicy"):
        assert objs[kind]["metadata"]["namespace"] == "fogfleet-system"
    binding = objs["ClusterRoleBinding"]
    assert binding["roleRef"]["name"] == objs["ClusterRole"]["metadata"]["name"]
    assert binding["subjects"] == [
        {"kind": "ServiceAccount", "name": "fogfleet-operator", "namespace": "fogfleet-system"}
    ]
    # kubectl apply -f applies files in name order: the namespace must come first.
    assert sorted(INSTALL.glob("*.yaml"))[0].name.startswith("00-namespace")


def test_cluster_role_is_least_privilege() -> None:
    rules = _install_objects()["ClusterRole"]["rules"]
    _assert_no_wildcards(rules)
    assert _grants(rules) == EXPECTED_RULES
    askers = _install_objects()[f"ClusterRole/{ASKERS}"]
    _assert_no_wildcards(askers["rules"])
    assert _grants(askers["rules"]) == ASKER_RULES
    labels = askers["metadata"]["labels"]
    for role in ("edit", "admin"):  # not view: asking creates an object
        assert labels[f"rbac.authorization.k8s.io/aggregate-to-{role}"] == "true"
    assert "rbac.authorization.k8s.io/aggregate-to-view" not in labels
    # kopf peering is off: no peering resources, and nothing touches secrets.
    resources = {r for _, r in _grants(rules)}
    assert not any("peering" in r for r in resources)
    assert "secrets" not in resources


def test_operator_deployment_is_locked_down() -> None:
    deployment = _install_objects()["Deployment"]
    spec = deployment["spec"]
    # two replicas, one leader: a rolling update never runs two reconcilers (the Lease decides)
    assert spec["replicas"] == 2
    assert spec["strategy"]["rollingUpdate"] == {"maxUnavailable": 0, "maxSurge": 1}
    pod = spec["template"]["spec"]
    assert pod["serviceAccountName"] == "fogfleet-operator"
    _assert_secure_pod(pod)
    env = {e["name"]: e for e in pod["containers"][0]["env"]}
    assert env["FOGFLEET_LEADER_ELECTION"]["value"] == "true"
    assert env["FOGFLEET_LEADER_ELECTION_IDENTITY"]["valueFrom"]["fieldRef"] == {
        "fieldPath": "metadata.name"
    }
    # never on a robot's own computer
    (term,) = pod["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"][
        "nodeSelectorTerms"
    ]
    assert term["matchExpressions"] == [
        {"key": "fogfleet.io/tier", "operator": "NotIn", "values": ["robot"]}
    ]
    selector = spec["selector"]["matchLabels"]
    assert selector.items() <= spec["template"]["metadata"]["labels"].items()


def test_leader_election_role_grants_only_leases_in_its_namespace() -> None:
    objs = _install_objects()
    role, binding = objs["Role"], objs["RoleBinding"]
    _assert_no_wildcards(role["rules"])
    assert _grants(role["rules"]) == {
        ("coordination.k8s.io", "leases"): {"get", "create", "update"}
    }
    assert binding["roleRef"]["name"] == role["metadata"]["name"]
    assert binding["subjects"][0]["name"] == "fogfleet-operator"


def test_network_policy_admits_only_probes_and_metrics() -> None:
    policy = _install_objects()["NetworkPolicy"]
    pod_labels = _install_objects()["Deployment"]["spec"]["template"]["metadata"]["labels"]
    assert policy["spec"]["podSelector"]["matchLabels"].items() <= pod_labels.items()
    (ingress,) = policy["spec"]["ingress"]
    assert sorted(p["port"] for p in ingress["ports"]) == [8080, 9100]


def test_operator_environment_is_what_fogfleet_settings_reads(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from fogfleet.settings import Settings

    container = _install_objects()["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    env = {e["name"]: e["value"] for e in container["env"] if "value" in e}
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    settings = Settings()
    assert settings.namespaces == []
    assert settings.standalone is True
    assert settings.leader_election is True and settings.lease_seconds == 15
    # Probes and scrapes reach the pod IP: the endpoints must not stay on 127.0.0.1.
    assert (settings.liveness_host, settings.liveness_port) == ("0.0.0.0", 8080)
    assert (settings.metrics_host, settings.metrics_port) == ("0.0.0.0", 9100)
    assert settings.log_format == "json"
    fields = {f"FOGFLEET_{name.upper()}" for name in Settings.model_fields}
    # Scheduler defaults are passed for when Settings grows them; nothing else may be unread.
    assert set(env) - fields <= {
        "FOGFLEET_SCHEDULER_POPULATION",
        "FOGFLEET_SCHEDULER_GENERATIONS",
        "FOGFLEET_SCHEDULER_TIME_BUDGET_MILLIS",
    }


# --- the chart ------------------------------------------------------------------------------


def _load_checker() -> Any:
    path = REPO / "tests" / "unit" / "api" / "openapi_check.py"
    spec = importlib.util.spec_from_file_location("_fogfleet_openapi_check", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _values() -> dict[str, Any]:
    values: dict[str, Any] = yaml.safe_load((CHART / "values.yaml").read_text())
    return values


def test_chart_metadata() -> None:
    chart = yaml.safe_load((CHART / "Chart.yaml").read_text())
    assert chart["apiVersion"] == "v2"
    assert (chart["name"], chart["version"], chart["appVersion"]) == ("fogfleet", "0.1.0", "0.1.0")
    assert chart["kubeVersion"] == ">=1.30.0-0"
    for name in ("_helpers.tpl", "NOTES.txt", "deployment.yaml", "clusterrole.yaml",
                 "clusterrolebinding.yaml", "serviceaccount.yaml"):  # fmt: skip
        assert (CHART / "templates" / name).is_file(), name


def test_values_schema_accepts_values_yaml_and_rejects_mistakes() -> None:
    validate = _load_checker().validate
    schema = json.loads((CHART / "values.schema.json").read_text())
    values = _values()
    assert validate(values, schema, dialect="jsonschema") == []
    bad = {**values, "logLevel": "verbose", "scheduler": {"population": 1}, "imageTag": "x"}
    errors = validate(bad, schema, dialect="jsonschema")
    assert any(e.startswith("logLevel:") for e in errors), errors
    assert any(e.startswith("scheduler.population:") for e in errors), errors
    assert any(e.startswith("imageTag: unknown field") for e in errors), errors


def test_values_defaults_match_the_plain_manifests() -> None:
    values = _values()
    container = _install_objects()["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    assert values["securityContext"] == container["securityContext"]
    assert values["resources"] == container["resources"]
    env = {e["name"]: e.get("value") for e in container["env"]}
    assert env["FOGFLEET_NAMESPACES"] == ",".join(values["watchNamespaces"])
    assert env["FOGFLEET_LOG_LEVEL"] == values["logLevel"]
    assert env["FOGFLEET_LOG_FORMAT"] == values["logFormat"]
    assert env["FOGFLEET_METRICS_PORT"] == str(values["metrics"]["port"])
    assert env["FOGFLEET_LIVENESS_PORT"] == str(values["healthPort"])
    assert env["FOGFLEET_WORKERS"] == str(values["workers"])
    assert env["FOGFLEET_DRIFT_INTERVAL_SECONDS"] == str(values["driftIntervalSeconds"])
    assert env["FOGFLEET_DEBOUNCE_SECONDS"] == str(values["debounceSeconds"])
    assert env["FOGFLEET_SCHEDULER_POPULATION"] == str(values["scheduler"]["population"])
    assert env["FOGFLEET_SCHEDULER_GENERATIONS"] == str(values["scheduler"]["generations"])
    assert env["FOGFLEET_SCHEDULER_TIME_BUDGET_MILLIS"] == str(
        values["scheduler"]["timeBudgetMillis"]
    )
    pod = _install_objects()["Deployment"]["spec"]["template"]["spec"]
    assert values["podSecurityContext"] == pod["securityContext"]
    assert values["affinity"] == pod["affinity"]
    assert values["replicaCount"] == _install_objects()["Deployment"]["spec"]["replicas"]
    assert env["FOGFLEET_LEASE_SECONDS"] == str(values["leaderElection"]["leaseSeconds"])


def test_chart_link_defaults_are_the_operators_own() -> None:
    from fogfleet.settings import Settings

    links, defaults = _values()["links"], Settings()
    assert links["intervalSeconds"] == defaults.link_interval_seconds
    assert links["nodeLabel"] == defaults.link_node_label


def test_chart_scaling_defaults_are_the_operators_own() -> None:
    from fogfleet.settings import Settings

    scaling, defaults = _values()["scaling"], Settings()
    assert scaling["intervalSeconds"] == defaults.scaling_interval_seconds
    assert scaling["rateWindowSeconds"] == defaults.rate_window_seconds


def test_chart_clusterrole_template_has_the_same_rules_as_the_manifest() -> None:
    # Without helm: the template's rules block is plain YAML between the metadata and the end.
    text = (CHART / "templates" / "clusterrole.yaml").read_text()
    block = text[text.index("rules:") : text.rindex("{{- end }}")]
    rules = yaml.safe_load(block)["rules"]
    assert _grants(rules) == EXPECTED_RULES
    text = (CHART / "templates" / "clusterrole-askers.yaml").read_text()
    block = text[text.index("rules:") : text.rindex("{{- end }}")]
    assert _grants(yaml.safe_load(block)["rules"]) == ASKER_RULES


def test_chart_crds_are_the_generated_crds() -> None:
    """The chart templates the generated CRDs (kept on uninstall), and has no crds/ folder."""
    from fogfleet.artefacts.crds import render_chart_crd_text

    for path in sorted((REPO / "crds").glob("*.yaml")):
        want = render_chart_crd_text(yaml.safe_load(path.read_text()))
        assert (CHART / "templates" / "crds" / path.name).read_text() == want, path.name
    assert {p.name for p in (CHART / "templates" / "crds").glob("*.yaml")} == {
        p.name for p in (REPO / "crds").glob("*.yaml")
    }
    assert not (CHART / "crds").exists()


def _helm() -> str | None:
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fogfleet"
    for candidate in (
        os.environ.get("FOGFLEET_HELM"),
        shutil.which("helm"),
        str(cache / "bin" / "helm"),
        str(cache / "prebuild" / "bin" / "helm"),
    ):
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return candidate
    return None


HELM = _helm()
needs_helm = pytest.mark.skipif(
    HELM is None,
    reason="no helm binary (FOGFLEET_HELM, PATH, ~/.cache/fogfleet/bin/helm): "
    "build it with `make cluster-tools`",
)


def _helm_env(tmp_path: Path) -> dict[str, str]:
    return {
        **os.environ,
        "HELM_CACHE_HOME": str(tmp_path / "cache"),
        "HELM_CONFIG_HOME": str(tmp_path / "config"),
        "HELM_DATA_HOME": str(tmp_path / "data"),
        "KUBECONFIG": str(tmp_path / "no-kubeconfig"),
    }


@needs_helm
def test_helm_lint_passes(tmp_path: Path) -> None:
    assert HELM is not None
    run = subprocess.run(
        [HELM, "lint", "--strict", str(CHART)],
        capture_output=True, text=True, env=_helm_env(tmp_path), timeout=60, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr


@needs_helm
def test_helm_template_renders_the_manifests_rbac_and_a_locked_down_pod(tmp_path: Path) -> None:
    assert HELM is not None
    run = subprocess.run(
        [HELM, "template", "fogfleet", str(CHART), "--namespace", "fogfleet-system",
         "--include-crds", "--kube-version", "1.30.0"],
        capture_output=True, text=True, env=_helm_env(tmp_path), timeout=60, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    docs = [d for d in yaml.safe_load_all(run.stdout) if d]
    by_kind: dict[str, list[dict[str, Any]]] = {}
    for doc in docs:
        by_kind.setdefault(doc["kind"], []).append(doc)
    assert len(by_kind["CustomResourceDefinition"]) == 4
    role, askers = sorted(by_kind["ClusterRole"], key=lambda r: len(r["metadata"]["name"]))
    assert askers["rules"] == _install_objects()[f"ClusterRole/{ASKERS}"]["rules"]
    assert askers["metadata"]["name"] == ASKERS
    manifest_rules = _install_objects()["ClusterRole"]["rules"]
    assert role["rules"] == manifest_rules
    assert role["metadata"]["name"] == "fogfleet-operator"
    (deployment,) = by_kind["Deployment"]
    assert deployment["metadata"]["namespace"] == "fogfleet-system"
    manifest = _install_objects()
    for kind in ("Role", "NetworkPolicy"):
        (rendered,) = by_kind[kind]
        assert (
            rendered["spec" if kind == "NetworkPolicy" else "rules"]
            == (manifest[kind]["spec" if kind == "NetworkPolicy" else "rules"])
        ), kind
    assert deployment["spec"]["strategy"] == manifest["Deployment"]["spec"]["strategy"]
    _assert_secure_pod(deployment["spec"]["template"]["spec"])
    (account,) = by_kind["ServiceAccount"]
    (binding,) = by_kind["ClusterRoleBinding"]
    assert binding["subjects"][0]["name"] == account["metadata"]["name"]
    assert (
        deployment["spec"]["template"]["spec"]["serviceAccountName"] == account["metadata"]["name"]
    )


@needs_helm
def test_helm_template_honours_watch_namespaces(tmp_path: Path) -> None:
    assert HELM is not None
    run = subprocess.run(
        [HELM, "template", "ff", str(CHART), "--set", "watchNamespaces={warehouse,lab}",
         "--kube-version", "1.30.0"],
        capture_output=True, text=True, env=_helm_env(tmp_path), timeout=60, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    deployment = next(d for d in yaml.safe_load_all(run.stdout) if d and d["kind"] == "Deployment")
    env = {
        e["name"]: e.get("value")
        for e in deployment["spec"]["template"]["spec"]["containers"][0]["env"]
    }
    assert env["FOGFLEET_NAMESPACES"] == "warehouse,lab"


# --- Dockerfile -----------------------------------------------------------------------------


def test_dockerfile_pins_python_and_runs_as_non_root() -> None:
    text = (REPO / "Dockerfile").read_text()
    base = re.search(r"^ARG PYTHON_IMAGE=(\S+)$", text, re.M)
    assert base is not None
    assert re.fullmatch(r"python:3\.11\.\d+-slim(-\w+)?(@sha256:[0-9a-f]{64})?", base.group(1))
    assert re.findall(r"^USER (\S+)$", text, re.M)[-1] == "65532:65532"
    assert "pip install --no-cache-dir ." in text
    assert 'ENTRYPOINT ["fogfleet"]' in text and 'CMD ["run"]' in text
    assert "HOME=/tmp" in text
    ignore = [
        line.strip()
        for line in (REPO / ".dockerignore").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    assert ignore[0] == "*" and "!operator/" in ignore and "!pyproject.toml" in ignore


def test_runtime_dependencies_are_pinned() -> None:
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    for dep in project["dependencies"]:
        assert re.fullmatch(r"[A-Za-z0-9_.\-\[\]]+==[0-9][\w.]*", dep), dep
