"""make e2e-kind / make e2e-k3d: the cluster configurations they generate, the commands they
run, and the refusal when Docker cannot start privileged containers (e2e/clusters)."""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from e2e.clusters import docker, layout
from e2e.clusters.__main__ import Provider, main
from e2e.portable import nodes

IMAGE = "example/node:v1"


def as_nodes(labelled: list[dict[str, str]]) -> list[dict[str, Any]]:
    """Ready Nodes carrying these labels, as the portable suite would read them."""
    return [
        {"metadata": {"name": f"n{i}", "labels": labels}, "spec": {},
         "status": {"conditions": [{"type": "Ready", "status": "True"}]}}
        for i, labels in enumerate(labelled)
    ]  # fmt: skip


def test_kind_makes_a_bare_control_plane_and_one_labelled_worker_per_layout_node() -> None:
    cfg = layout.kind_config(IMAGE)
    assert cfg["apiVersion"] == "kind.x-k8s.io/v1alpha4" and cfg["kind"] == "Cluster"
    assert cfg["networking"]["apiServerAddress"] == "127.0.0.1"
    control, *workers = cfg["nodes"]
    assert control == {"role": "control-plane", "image": IMAGE}
    assert [w["role"] for w in workers] == ["worker"] * len(layout.WORKERS)
    assert all(w["image"] == IMAGE for w in workers)
    assert [w["labels"] for w in workers] == [w.labels for w in layout.WORKERS]
    # what the portable suite needs: two robots and an edge node
    topo = nodes.pick(as_nodes([n.get("labels", {}) for n in cfg["nodes"]]))
    assert len(topo.robots) == 2 and len(topo.offload) == 1 and topo.node_selector == {}


def test_k3d_labels_each_agent_as_its_layout_node_and_leaves_the_server_bare() -> None:
    cfg = layout.k3d_config(IMAGE, name="c1", api_port=1234)
    assert cfg["apiVersion"] == "k3d.io/v1alpha5" and cfg["kind"] == "Simple"
    assert cfg["metadata"] == {"name": "c1"} and cfg["image"] == IMAGE
    assert cfg["servers"] == 1 and cfg["agents"] == len(layout.WORKERS)
    assert cfg["kubeAPI"] == {"hostIP": "127.0.0.1", "hostPort": "1234"}
    per_agent: dict[str, dict[str, str]] = {}
    for entry in cfg["options"]["k3s"]["nodeLabels"]:
        (target,) = entry["nodeFilters"]
        key, _, value = entry["label"].partition("=")
        per_agent.setdefault(target, {})[key] = value
    assert per_agent == {f"agent:{i}": w.labels for i, w in enumerate(layout.WORKERS)}
    assert cfg["options"]["kubeconfig"]["updateDefaultKubeconfig"] is False
    topo = nodes.pick(as_nodes(list(per_agent.values())))
    assert len(topo.robots) == 2 and len(topo.offload) == 1


def test_the_node_images_are_pinned_in_versions_env() -> None:
    assert layout.node_image("kind").startswith("kindest/node:v")
    assert layout.node_image("k3d").startswith("rancher/k3s:v")


@pytest.mark.parametrize("tool", ["kind", "k3d"])
def test_each_tool_creates_loads_and_deletes_the_named_cluster(tool: str) -> None:
    p = Provider(tool, "c1", Path("/tmp/c.json"))
    assert p.create()[0] == tool and "/tmp/c.json" in p.create()
    assert "c1" in p.kubeconfig() and "c1" in p.delete()
    load = p.load("ghcr.io/fogfleet/fogfleet:0.1.0")
    assert "ghcr.io/fogfleet/fogfleet:0.1.0" in load and "c1" in load
    assert p.document(IMAGE)["apiVersion"].startswith("kind." if tool == "kind" else "k3d.")


def fake(answers: dict[str, tuple[int, str]]) -> tuple[list[list[str]], Any]:
    calls: list[list[str]] = []

    def run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
        calls.append(list(cmd))
        code, err = answers.get(cmd[1], (0, ""))
        return subprocess.CompletedProcess(list(cmd), code, "", err)

    return calls, run


def test_no_docker_engine_is_refused_with_dockers_words() -> None:
    calls, run = fake({"info": (1, "Cannot connect to the Docker daemon at unix:///x.sock.")})
    with pytest.raises(docker.Refused) as err:
        docker.check("kind", IMAGE, run=run, which=lambda t: t)
    assert str(err.value) == (
        "make e2e-kind: the Docker engine is not reachable: "
        "Cannot connect to the Docker daemon at unix:///x.sock."
    )
    assert [c[1] for c in calls] == ["info"]  # nothing started


def test_an_engine_without_privileged_containers_is_refused_before_the_tool_is_looked_for() -> None:
    said = "docker: Error response from daemon: operation not permitted (CAP_SYS_RESOURCE)."
    calls, run = fake({"run": (126, f"starting\n{said}\n")})
    with pytest.raises(docker.Refused) as err:
        docker.check("k3d", IMAGE, run=run, which=lambda t: None if t == "k3d" else t)
    assert "cannot start a privileged container of example/node:v1" in str(err.value)
    assert str(err.value).endswith(said) and str(err.value).startswith("make e2e-k3d:")
    assert calls[1][:6] == ["docker", "run", "--rm", "--privileged", "--network", "none"]


def test_a_docker_that_can_is_let_through_once_the_tool_is_there() -> None:
    _, run = fake({})
    docker.check("kind", IMAGE, run=run, which=lambda t: t)
    with pytest.raises(docker.Refused, match="'kind' is not on PATH"):
        docker.check("kind", IMAGE, run=run, which=lambda t: None if t == "kind" else t)


def test_the_target_exits_2_with_one_line_and_creates_nothing_under_a_fake_docker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A fake ``docker`` command on PATH that answers info but refuses --privileged; ``kind``
    records any call (there must be none)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "docker").write_text(
        "#!/bin/sh\n"
        'if [ "$1" = info ]; then echo 28.2.2; exit 0; fi\n'
        'echo "docker: Error response from daemon: privileged mode is disabled." >&2\n'
        "exit 125\n"
    )
    (bin_dir / "kind").write_text(f'#!/bin/sh\necho "$@" >> {tmp_path}/kind-calls\n')
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    monkeypatch.setenv("PATH", str(bin_dir))
    assert main(["kind"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "privileged mode is disabled." in err[0], err
    assert not (tmp_path / "kind-calls").exists()
