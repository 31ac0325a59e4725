"""The README, followed literally on the bed: what a new user types, in a shell of their own.

1. The Quick start's `make demo` (its cluster part, ``e2e/demo.py``) leaves the warehouse fleet
   Ready with the operator installed in-cluster by Helm on a real node, and prints the lines
   that point a plain shell at the bed; in such a shell `kubectl get robotfleets -A` shows the
   fleet, and another example applies and gets Ready.
2. "Install into a cluster" with plain manifests: the README's own `kubectl apply` line puts the
   operator on a real node that is not a robot (never on a kwok node: they are tainted for
   planned pods only), and the fleet of an example applied next gets Ready from it.

Each test removes what it installed (`e2e/demo.py remove`, `kubectl delete -f
manifests/install/`) so the operators of the other suites run alone.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import ROOT, install_crds, wait_ready

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the README's demo and install on the local bed"),
    pytest.mark.real,
    pytest.mark.incluster,
    pytest.mark.timeout(900),
]

README = ROOT / "README.md"
SYSTEM = "fogfleet-system"
OPERATOR = "app.kubernetes.io/component=operator"


def readme_commands(section: str) -> list[str]:
    """The shell commands of the README section's first ``bash`` block, comments dropped."""
    text = README.read_text()
    body = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", body, re.S)
    assert block, f"README section {section!r} has no bash block"
    lines = [line.split("  #", 1)[0].strip() for line in block.group(1).splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def user_shell(script: str, env: dict[str, str], timeout: float = 300) -> str:
    """``bash -c script`` in the repository, with only the environment a user would have."""
    proc = subprocess.run(
        ["bash", "-c", f"set -euo pipefail\n{script}"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, f"{script}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def plain_env() -> dict[str, str]:
    """A login-like environment: no KUBECONFIG, no harness variables."""
    keep = ("HOME", "PATH", "LANG", "USER", "TERM")
    return {k: os.environ[k] for k in keep if k in os.environ}


def assert_operator_on_real_non_robot_nodes(kube: Kube, cluster: Cluster, replicas: int) -> None:
    pods = kube.kubectl_json("get", "pods", "-n", SYSTEM, "-l", OPERATOR)["items"]
    running = [p for p in pods if p["status"].get("phase") == "Running"]
    assert len(running) == replicas, [p["metadata"]["name"] for p in pods]
    for pod in running:
        node = pod["spec"]["nodeName"]
        labels = kube.kubectl_json("get", "node", node)["metadata"]["labels"]
        assert node in cluster.real_nodes, f"operator on {node}, not on a real node"
        assert labels.get("fogfleet.io/tier") != "robot", f"operator on the robot {node}"


def test_the_demo_leaves_the_warehouse_ready_with_an_in_cluster_operator_and_a_shell_reaches_it(
    kube: Kube, cluster: Cluster
) -> None:
    demo = subprocess.run(
        [sys.executable, str(ROOT / "e2e" / "demo.py")],
        cwd=ROOT, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    try:
        assert demo.returncode == 0, demo.stdout[-3000:] + demo.stderr[-3000:]
        exports = [
            ln.strip() for ln in demo.stdout.splitlines() if ln.strip().startswith("export ")
        ]
        assert {e.split("=", 1)[0] for e in exports} == {"export KUBECONFIG", "export PATH"}
        assert_operator_on_real_non_robot_nodes(kube, cluster, replicas=2)
        env = plain_env()
        listed = user_shell("\n".join([*exports, "kubectl get robotfleets -A"]), env)
        (row,) = [ln.split() for ln in listed.splitlines() if ln.startswith("warehouse ")]
        assert row[1] == "warehouse" and "True" in row, listed
        # another example, as the demo's last lines say
        user_shell("\n".join([*exports, "kubectl apply -f manifests/examples/single-robot/"]), env)
        wait_ready(kube, "single-robot", name="single-robot", timeout=240)
        assert "make cluster-down" in demo.stdout
    finally:
        subprocess.run(
            [sys.executable, str(ROOT / "e2e" / "demo.py"), "remove"],
            cwd=ROOT, timeout=300, check=False,
        )  # fmt: skip
        for ns in ("warehouse", "single-robot"):  # the next test applies single-robot again
            kube.kubectl("wait", "--for=delete", f"namespace/{ns}", "--timeout=240s",
                         check=False, timeout=260)  # fmt: skip


def test_the_readme_install_puts_the_operator_on_a_real_node_and_it_runs_a_fleet(
    kube: Kube, cluster: Cluster
) -> None:
    (install,) = [c for c in readme_commands("Install into a cluster") if c.startswith("kubectl")]
    assert install == "kubectl apply -f crds/ -f manifests/install/"
    install_crds(kube)  # the README's line applies them too; this only waits for Established
    env = dict(plain_env(), KUBECONFIG=str(cluster.kubeconfig))
    env["PATH"] = f"{cluster.bin_dir}:{env.get('PATH', '')}"
    try:
        user_shell(install, env)
        kube.kubectl("rollout", "status", "deployment", "-n", SYSTEM, "--timeout=240s",
                     "fogfleet-operator", timeout=260)  # fmt: skip
        assert_operator_on_real_non_robot_nodes(kube, cluster, replicas=2)
        user_shell("kubectl apply -f manifests/examples/single-robot/", env)
        wait_ready(kube, "single-robot", name="single-robot", timeout=240)
    finally:
        kube.kubectl("delete", "namespace", "single-robot", "--ignore-not-found", "--wait=true",
                     check=False, timeout=240)  # fmt: skip
        kube.kubectl("delete", "-f", str(Path(ROOT, "manifests", "install")), "--ignore-not-found",
                     "--wait=true", check=False, timeout=240)  # fmt: skip
