"""Every pod ``fogfleet render`` prints for the examples meets the restricted Pod Security
Standard (issue 37, item 8; the rules: e2e/podsecurity/restricted.py, after
https://kubernetes.io/docs/concepts/security/pod-security-standards/), standbys and
discovery servers included; each example's namespace enforces the level its pods need."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from e2e.podsecurity.restricted import violations

from fogfleet.api.labels import LABEL_COMPONENT
from fogfleet.commandline.cli import main
from fogfleet.render.ros import COMPONENT_DISCOVERY

EXAMPLES = Path(__file__).resolve().parents[3] / "manifests" / "examples"
RENDERED = ["single-robot", "warehouse-lite", "shared-detector", "split-network"]
ENFORCE = "pod-security.kubernetes.io/enforce"
STANDBY_MODULE = "object-pose-estimation"  # offloaded in this plan (seed 1), so it gets a standby


def _render(folder: Path, capsys: pytest.CaptureFixture[str]) -> list[dict[str, Any]]:
    code = main(["render", str(folder), "--generations", "2", "--population", "6", "--seed", "1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return [d for d in yaml.safe_load_all(out) if d]


def _pods(docs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {
        d["metadata"]["name"]: d["spec"]["template"]["spec"]
        for d in docs
        if d["kind"] in ("Deployment", "StatefulSet", "DaemonSet", "Job")
    }


@pytest.mark.parametrize("example", RENDERED)
def test_rendered_pods_meet_restricted(example: str, capsys: pytest.CaptureFixture[str]) -> None:
    docs = _render(EXAMPLES / example, capsys)
    pods = _pods(docs)
    assert pods
    components = {d["metadata"]["labels"].get(LABEL_COMPONENT) for d in docs}
    assert COMPONENT_DISCOVERY in components, sorted(pods)  # discovery servers
    bad = {name: v for name, spec in pods.items() if (v := violations(spec))}
    assert not bad, bad


def test_standbys_meet_restricted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """single-robot with an on-board fallback on an offloaded module (docs/ros2.md), so a
    standby is rendered too."""
    for f in (EXAMPLES / "single-robot").glob("*.yaml"):
        shutil.copy(f, tmp_path / f.name)
    modules = list(yaml.safe_load_all((tmp_path / "modules.yaml").read_text()))
    for m in modules:
        if m and m["metadata"]["name"] == STANDBY_MODULE:
            m["spec"]["fallback"] = {"mode": "onboard"}
    (tmp_path / "modules.yaml").write_text(yaml.safe_dump_all(modules))
    docs = _render(tmp_path, capsys)
    standbys = [
        d
        for d in docs
        if d["kind"] == "Deployment"
        and d["metadata"].get("labels", {}).get("app.kubernetes.io/component") == "fallback-standby"
    ]
    assert standbys, "no standby rendered: the fallback did not apply"
    bad = {name: v for name, spec in _pods(docs).items() if (v := violations(spec))}
    assert not bad, bad


def test_the_rules_refuse_what_restricted_refuses() -> None:
    """The checker is not vacuous: each rule fires on the pod-template example's exceptions."""
    spec = {
        "volumes": [{"name": "camera", "hostPath": {"path": "/dev/video0"}}],
        "securityContext": {"seccompProfile": {"type": "Unconfined"}},
        "containers": [
            {
                "name": "m",
                "securityContext": {"capabilities": {"add": ["SYS_NICE"]}, "privileged": True},
            }
        ],
    }
    found = " ".join(violations(spec))
    for word in (
        "hostPath",
        "privileged",
        "SYS_NICE",
        "drop ALL",
        "runAsNonRoot",
        "allowPrivilegeEscalation",
        "Unconfined",
    ):
        assert word in found, (word, found)


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.iterdir() if p.is_dir()))
def test_namespaces_enforce_the_level_their_pods_need(example: str) -> None:
    ns = yaml.safe_load((EXAMPLES / example / "00-namespace.yaml").read_text())
    level = ns["metadata"].get("labels", {}).get(ENFORCE)
    templates = [
        d.get("spec", {}).get("template", {})
        for f in (EXAMPLES / example).glob("*.yaml")
        for d in yaml.safe_load_all(f.read_text())
        if d and d.get("kind") == "SoftwareModule"
    ]
    needs_more = any(
        any("hostPath" in v for v in t.get("volumes", ()))
        or (t.get("securityContext") or {}).get("capabilities", {}).get("add")
        for t in templates
    )
    assert level == ("privileged" if needs_more else "restricted"), (example, level)
