"""The loader reads a file's documents as kubectl does (cli-runtime's ``StreamVisitor``): an
empty document is nothing, anything else must be an object with a kind and an apiVersion; an
object of another group is skipped and named where a fleet misses one of its name; a bad object
never hides the objects after it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from fogfleet.api.loader import API_VERSION, Catalog, Skipped, load_paths
from fogfleet.errors import InvalidSpec

NODE = {
    "apiVersion": API_VERSION,
    "kind": "ComputeNode",
    "metadata": {"name": "edge-1"},
    "spec": {"tier": "edge", "hardwareType": "x86", "capacity": {"cpu": "4", "memory": "8Gi"}},
}


def _node(name: str) -> dict[str, object]:
    return {**NODE, "metadata": {"name": name}}


@pytest.mark.parametrize(
    ("name", "text", "what"),
    [
        ("seq.yaml", "- a: 1\n- b: 2\n", "a list"),
        ("scalar.yaml", "hello\n", "a string"),
        ("array.json", '[{"kind": "ComputeNode"}]', "a list"),
        ("number.yaml", "---\n42\n", "a number"),
    ],
)
def test_a_document_that_is_not_an_object_is_refused_naming_the_file(
    tmp_path: Path, name: str, text: str, what: str
) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InvalidSpec) as info:
        load_paths([tmp_path])
    assert info.value.obj == str(path) and info.value.field == "document 1"
    assert f"is {what}, not an object" in info.value.message


def test_empty_documents_are_nothing_as_in_kubectl(tmp_path: Path) -> None:
    (tmp_path / "empty.yaml").write_text("---\n# a comment\n---\nnull\n---\n")
    catalog = load_paths([tmp_path])
    assert catalog == Catalog()


@pytest.mark.parametrize("missing", ["kind", "apiVersion"])
def test_an_object_without_kind_or_apiversion_is_refused_not_skipped(
    tmp_path: Path, missing: str
) -> None:
    doc = {k: v for k, v in NODE.items() if k != missing}
    (tmp_path / "node.yaml").write_text(yaml.safe_dump(doc))
    errors: list[InvalidSpec] = []
    catalog = load_paths([tmp_path], errors)
    assert catalog.ignored == [] and catalog.nodes == {}
    [error] = errors
    assert error.field.endswith(missing) and str(tmp_path / "node.yaml") in str(error)
    assert "missing" in error.message and "kubectl refuses" in error.message


def test_a_skipped_object_says_what_fogfleet_reads() -> None:
    misspelt = Skipped("ComputeNode", "edge-1", "fogfleet.i0/v1alpha1", "nodes.yaml")
    assert misspelt.why == (
        f"apiVersion fogfleet.i0/v1alpha1 is not fogfleet's (it reads {API_VERSION})"
    )
    other = Skipped("Node", "edge-1", "v1", "nodes.yaml")
    assert other.why == (
        "kind Node (apiVersion v1) is not fogfleet's (it reads ComputeNode, SoftwareModule "
        f"and RobotFleet of {API_VERSION})"
    )


def test_a_missing_reference_names_the_skipped_object_its_file_and_why(tmp_path: Path) -> None:
    catalog = Catalog(
        ignored=[
            Skipped("Namespace", "edge-1", "v1", "ns.yaml"),
            Skipped("ComputeNode", "edge-1", "fogfleet.i0/v1alpha1", "nodes.yaml"),
            Skipped("ComputeNode", "edge-2", "fogfleet.i0/v1alpha1", "nodes.yaml"),
        ]
    )
    message = catalog.missing("ComputeNode 'edge-1'", "edge-1")
    assert message == (
        "ComputeNode 'edge-1' does not exist; nodes.yaml defines ComputeNode/edge-1, skipped: "
        f"apiVersion fogfleet.i0/v1alpha1 is not fogfleet's (it reads {API_VERSION}); "
        "ns.yaml defines Namespace/edge-1, skipped: kind Namespace (apiVersion v1) is not "
        f"fogfleet's (it reads ComputeNode, SoftwareModule and RobotFleet of {API_VERSION})"
    )


def test_a_bad_list_item_or_a_duplicate_does_not_hide_the_items_after_it(
    tmp_path: Path,
) -> None:
    items = [
        _node("a"),
        3,
        _node("a"),
        {**_node("b"), "spec": {**NODE["spec"], "tier": "moon"}},
        _node("c"),
    ]
    (tmp_path / "list.yaml").write_text(
        yaml.safe_dump({"apiVersion": "v1", "kind": "List", "items": items})
    )
    errors: list[InvalidSpec] = []
    catalog = load_paths([tmp_path], errors)
    assert sorted(catalog.nodes) == ["a", "c"]
    assert [(e.obj.split(" ")[0], e.field) for e in errors][:3] == [
        ("List", "items[1]"),
        ("ComputeNode/a", "metadata.name"),
        ("ComputeNode/b", "spec.tier"),
    ]
