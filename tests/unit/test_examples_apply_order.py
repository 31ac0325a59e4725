"""Each folder of manifests/examples applies on its own: `kubectl apply -f <folder>/` on a fresh
cluster that has only the CRDs.

kubectl reads a folder's .json, .yaml and .yml files in name order (not its subfolders) and
each file's objects in order, and stops at the first object whose namespace does not exist. So
a folder creates its namespaces before anything in them (`00-namespace.yaml`), uses no
namespace it does not create (or `default`), and holds nothing that is not a Kubernetes object.
Cluster-wide objects two folders both declare (ComputeNodes) are the same in both, so the
folders can run side by side. e2e/tests/test_examples.py applies each folder on the bed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.api.v1alpha1.robotfleet import RosSettings

EXAMPLES = Path(__file__).resolve().parents[2] / "manifests" / "examples"
FOLDERS = sorted(p.name for p in EXAMPLES.iterdir() if p.is_dir())
KUBECTL_READS = (".json", ".yaml", ".yml")
CLUSTER_SCOPED = {
    "Namespace",
    "ComputeNode",
    "Node",
    "PersistentVolume",
    "StorageClass",
    "PriorityClass",
    "ClusterRole",
    "ClusterRoleBinding",
    "CustomResourceDefinition",
}
FRESH_CLUSTER = {"default"}
WORKLOAD_IMAGE = RosSettings.model_fields["discovery_server_image"].default

Doc = dict[str, Any]


def _docs(folder: Path) -> list[tuple[str, Doc]]:
    """(file name, object) in kubectl's order."""
    return [
        (path.name, doc)
        for path in sorted(folder.iterdir())
        if path.is_file() and path.suffix in KUBECTL_READS
        for doc in yaml.safe_load_all(path.read_text())
        if doc is not None
    ]


def _images(node: Any) -> list[str]:
    if isinstance(node, dict):
        own = [str(node["image"])] if isinstance(node.get("image"), str) else []
        return own + [i for v in node.values() for i in _images(v)]
    if isinstance(node, list):
        return [i for v in node for i in _images(v)]
    return []


def test_there_are_example_folders() -> None:
    assert {"warehouse", "single-robot", "shared-detector", "pod-template"} <= set(FOLDERS)


@pytest.mark.parametrize("example", FOLDERS)
def test_every_file_an_apply_of_the_folder_reads_is_kubernetes_objects(example: str) -> None:
    folder = EXAMPLES / example
    assert not [p.name for p in folder.iterdir() if p.is_dir()], "kubectl -f does not recurse"
    docs = _docs(folder)
    assert docs
    for name, doc in docs:
        assert isinstance(doc, dict), f"{example}/{name}: not an object"
        missing = [k for k in ("apiVersion", "kind") if not doc.get(k)]
        assert not missing, f"{example}/{name}: no {', '.join(missing)}: not a Kubernetes object"
        assert (doc.get("metadata") or {}).get("name"), f"{example}/{name}: no metadata.name"


@pytest.mark.parametrize("example", FOLDERS)
def test_an_example_applies_in_kubectls_order_to_a_fresh_cluster(example: str) -> None:
    namespaces = set(FRESH_CLUSTER)
    for name, doc in _docs(EXAMPLES / example):
        what = f"{example}/{name}: {doc['kind']}/{doc['metadata']['name']}"
        if doc["kind"] == "Namespace":
            namespaces.add(doc["metadata"]["name"])
        if doc["kind"] in CLUSTER_SCOPED:
            assert "namespace" not in doc["metadata"], f"{what} is cluster-wide"
            continue
        ns = doc["metadata"].get("namespace")
        assert ns, f"{what} names no namespace: it would land in the user's current one"
        assert ns in namespaces, f"{what} is in namespace {ns}, which does not exist yet"


@pytest.mark.parametrize("example", FOLDERS)
def test_an_example_names_only_the_workload_image_the_bed_builds(example: str) -> None:
    images = {i for _, doc in _docs(EXAMPLES / example) for i in _images(doc.get("spec"))}
    assert images <= {WORKLOAD_IMAGE}, f"{example}: {sorted(images - {WORKLOAD_IMAGE})}"


def test_a_compute_node_two_examples_declare_is_the_same_object_in_both() -> None:
    seen: dict[str, tuple[str, Doc]] = {}
    for example in FOLDERS:
        for _, doc in _docs(EXAMPLES / example):
            if doc["kind"] != "ComputeNode":
                continue
            name = doc["metadata"]["name"]
            first = seen.setdefault(name, (example, doc))
            assert first[1] == doc, f"ComputeNode {name} differs in {first[0]} and {example}"


def test_the_single_robot_runs_the_warehouses_modules_in_its_own_namespace() -> None:
    def modules(example: str) -> dict[str, Doc]:
        docs = yaml.safe_load_all((EXAMPLES / example / "modules.yaml").read_text())
        return {d["metadata"]["name"]: {**d, "metadata": {}} for d in docs if d}

    assert modules("single-robot") == modules("warehouse")
