"""Each folder of manifests/examples on its own, as a new user would try it: one
`kubectl apply -f <folder>/` on a cluster with only the CRDs, every RobotFleet in it Ready
with every pod of the fleet Running, then `kubectl delete -f <folder>/` and its namespaces
gone before the next folder.

The examples' ComputeNodes name the bed's Nodes: the warehouse's robot-1..5, edge-1..6 and
cloud-1 and the single robot's solo-robot and solo-edge are kwok nodes (e2e/bed/nodes.yaml;
their pods are Running without containers), warehouse-lite's bed-robot-1, bed-robot-2 and
bed-edge-1 are the bed's real nodes (marker ``real``). A test that replaced the kwok nodes
(`harness.py nodes --robots N`) is undone here: nodes.yaml's set comes back.

tests/unit/test_examples_apply_order.py checks the same folders offline (kubectl's order,
namespaces first, only Kubernetes objects, only the bed's workload image).

    pytest e2e/tests/test_examples.py --with-e2e              # every folder, about 5 minutes
    pytest e2e/tests/test_examples.py --with-e2e -k single-robot
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

from e2e.bed import fakenodes
from e2e.bed.base import NODES_FILE
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import EXAMPLES, Operator, wait_ready
from fogfleet.api.labels import LABEL_FLEET
from fogfleet.render.deployments import label_value

READY_SECONDS = 300  # the warehouse's 40 modules: a 100 x 100 NSGA-II run, then 45 pods
GONE_SECONDS = 180  # a namespace goes once its pods have (real ones stop in seconds)

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the examples' ComputeNodes name the bed's kwok nodes (nodes.yaml)"),
    pytest.mark.examples,
    pytest.mark.timeout(READY_SECONDS + GONE_SECONDS + 240),
]

Obj = dict[str, Any]


def _folders() -> list[Any]:
    real = {"warehouse-lite", "split-network"}  # their ComputeNodes are the bed's real nodes
    return [
        pytest.param(p.name, marks=[pytest.mark.real] if p.name in real else [], id=p.name)
        for p in sorted(EXAMPLES.iterdir())
        if p.is_dir()
    ]


def _objects(folder: Path) -> list[Obj]:
    """The folder's objects in kubectl's order (files by name, objects in file order)."""
    return [
        doc
        for path in sorted(folder.iterdir())
        if path.suffix in (".json", ".yaml", ".yml")
        for doc in yaml.safe_load_all(path.read_text())
        if isinstance(doc, dict)
    ]


def _names(objects: list[Obj], kind: str) -> list[str]:
    return [o["metadata"]["name"] for o in objects if o["kind"] == kind]


def _exists(kube: Kube, *args: str) -> bool:
    return kube.kubectl("get", *args, "-o", "name", check=False).returncode == 0


def _ready_nodes(kube: Kube) -> set[str]:
    ready = set()
    for node in kube.kubectl_json("get", "nodes")["items"]:
        conds = {c["type"]: c["status"] for c in node.get("status", {}).get("conditions", [])}
        if conds.get("Ready") == "True":
            ready.add(node["metadata"]["name"])
    return ready


def _bed_fake_nodes() -> set[str]:
    docs = yaml.safe_load_all(NODES_FILE.read_text())
    return {
        d["metadata"]["name"]
        for d in docs
        if d
        and d["kind"] == "Node"
        and "kwok.x-k8s.io/node" in d["metadata"].get("annotations", {})
    }


def _ensure_nodes(kube: Kube, wanted: set[str]) -> None:
    """Every Node the example's ComputeNodes name is Ready: nodes.yaml's kwok set is restored
    if another test replaced it; a missing real node (or any node off the bed) skips."""
    missing = wanted - _ready_nodes(kube)
    if missing and kube.cluster is not None and missing <= _bed_fake_nodes():
        fakenodes.create_nodes()  # back to nodes.yaml's kwok nodes
        missing = wanted - _ready_nodes(kube)
    if missing:
        pytest.skip(f"needs the Nodes {', '.join(sorted(missing))} (the bed's nodes.yaml)")


@contextmanager
def _operator(
    kube: Kube, namespaces: list[str], log: Path, diagnostics: list[Any]
) -> Iterator[Operator]:
    op = Operator(kube.kubeconfig, namespaces, log)
    diagnostics.append(lambda: (f"operator log ({', '.join(namespaces)})", op.logs(150)))
    op.start().wait_live()
    try:
        yield op
    finally:
        op.stop()


def _delete(kube: Kube, folder: Path, namespaces: list[str]) -> None:
    """`kubectl delete -f <folder>/` (the fleets first, so a running operator forgets them
    before their namespace goes); returns when every namespace of the folder is gone."""
    for ns in namespaces:
        if _exists(kube, "namespace", ns):
            kube.kubectl(
                "delete", "robotfleets", "--all", "-n", ns, "--wait=true", "--timeout=90s",
                check=False, timeout=120,
            )  # fmt: skip
    kube.kubectl("delete", "-f", str(folder), "--ignore-not-found", "--wait=false", timeout=120)
    for ns in namespaces:
        kube.wait_for(
            f"namespace {ns} gone", lambda ns=ns: not _exists(kube, "namespace", ns),
            timeout=GONE_SECONDS, interval=2,
        )  # fmt: skip


def _pods_running(kube: Kube, namespace: str, fleet: str) -> tuple[bool, str]:
    """Every pod of the fleet Running and as many as each of its Deployments wants."""
    selector = f"{LABEL_FLEET}={label_value(fleet)}"
    pods = [
        p
        for p in kube.kubectl_json("get", "pods", "-n", namespace, "-l", selector)["items"]
        if not p["metadata"].get("deletionTimestamp")
    ]
    not_running = [
        f"{p['metadata']['name']} {p['status'].get('phase')}"
        for p in pods
        if p["status"].get("phase") != "Running"
    ]
    if not_running:
        return False, f"not Running: {', '.join(not_running[:10])}"
    deps = kube.kubectl_json("get", "deployments", "-n", namespace, "-l", selector)["items"]
    if not deps:
        return False, "no Deployments yet"
    for dep in deps:
        match = dep["spec"]["selector"].get("matchLabels") or {}
        have = sum(match.items() <= (p["metadata"].get("labels") or {}).items() for p in pods)
        if have < int(dep["spec"].get("replicas", 1)):
            return False, f"{dep['metadata']['name']}: {have} of {dep['spec']['replicas']} pods"
    return True, f"{len(pods)} pods Running in {len(deps)} Deployments"


def _wait_running(kube: Kube, namespace: str, fleet: str, timeout: float = 120) -> str:
    """Waits for `_pods_running`; returns its summary, or fails with what it saw last."""
    seen = [""]

    def running() -> bool:
        ok, seen[0] = _pods_running(kube, namespace, fleet)
        return ok

    try:
        kube.wait_for(f"every pod of {namespace}/{fleet} Running", running, timeout=timeout)
    except AssertionError as exc:
        raise AssertionError(f"{exc}: {seen[0]}") from None
    return seen[0]


@pytest.mark.parametrize("example", _folders())
def test_an_example_folder_applies_alone_and_every_fleet_in_it_runs(
    kube: Kube, crds: None, example: str, tmp_path: Path, diagnostics: list[Any]
) -> None:
    folder = EXAMPLES / example
    objects = _objects(folder)
    namespaces = _names(objects, "Namespace")
    fleets = [(o["metadata"]["namespace"], o["metadata"]["name"]) for o in objects
              if o["kind"] == "RobotFleet"]  # fmt: skip
    _ensure_nodes(kube, set(_names(objects, "ComputeNode")))
    if any(_exists(kube, "namespace", ns) for ns in namespaces):  # left by an earlier run
        _delete(kube, folder, namespaces)

    # one apply of the whole folder; the operator starts after it (it needs no finalizer, so
    # the cleanup in `finally` works with or without it)
    try:
        kube.kubectl("apply", "-f", str(folder))
        listed = kube.kubectl("get", "-f", str(folder), "-o", "name").stdout.split()
        assert len(listed) == len(objects), listed
        with _operator(kube, namespaces, tmp_path / "operator.log", diagnostics):
            for ns, name in fleets:
                wait_ready(kube, ns, name, timeout=READY_SECONDS)
                print(f"\n{example}: {ns}/{name} Ready, {_wait_running(kube, ns, name)}")
            _delete(kube, folder, namespaces)  # as a user would: the operator still runs
    finally:
        _delete(kube, folder, namespaces)
    assert not any(_exists(kube, "computenode", n) for n in _names(objects, "ComputeNode"))
