"""Input read the way kubectl reads it: numbers, duplicate keys, encodings and List kinds."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from fogfleet.api.kubeyaml import read_documents, safe_load
from fogfleet.api.loader import load_paths
from fogfleet.errors import InvalidSpec

REPO = Path(__file__).resolve().parents[3]
LITE = REPO / "manifests" / "examples" / "warehouse-lite"


@pytest.mark.parametrize(
    ("text", "value"),
    [("5e0", 5.0), ("1.0e30", 1e30), ("1e3", 1000.0), ("-2.5E-3", -0.0025), (".5", 0.5)],
)
def test_exponent_forms_are_numbers_as_in_go_yaml(text: str, value: float) -> None:
    assert safe_load(f"x: {text}")["x"] == value


def test_ints_quoted_numbers_and_dates_stay_what_kubectl_reads() -> None:
    doc = safe_load("a: 12\nb: '5e0'\nc: 2024-02-30\nd: 1e\n")
    assert doc == {"a": 12, "b": "5e0", "c": "2024-02-30", "d": "1e"}
    assert isinstance(doc["a"], int)


def test_a_duplicate_key_is_refused_with_file_line_and_key(tmp_path: Path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text("kind: ComputeNode\nspec:\n  tier: robot\n  tier: edge\n")
    with pytest.raises(InvalidSpec) as info:
        read_documents(path)
    assert info.value.obj == str(path)
    assert info.value.field == "line 4"
    assert "duplicate key 'tier'" in info.value.message and "line 3" in info.value.message


def test_a_merge_key_may_be_overridden() -> None:
    assert safe_load("a: &a {x: 1}\nb: {<<: *a, x: 2}")["b"] == {"x": 2}


def test_a_file_that_is_not_utf8_names_the_file_and_the_byte(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes("kind: ComputeNode\nmetadata: {name: g\xe9ant}\n".encode("latin-1"))
    with pytest.raises(InvalidSpec) as info:
        load_paths([path])
    assert info.value.obj == str(path)
    assert "not UTF-8" in info.value.message and "0xe9" in info.value.message
    assert "line 2" in info.value.message


def test_a_utf8_byte_order_mark_is_read(tmp_path: Path) -> None:
    path = tmp_path / "bom.yaml"
    path.write_bytes(b"\xef\xbb\xbfa: 1\n")
    assert read_documents(path) == [{"a": 1}]


def test_list_items_are_read_as_objects(tmp_path: Path) -> None:
    docs = [d for f in sorted(LITE.glob("*.yaml")) for d in yaml.safe_load_all(f.read_text())]
    fog = [d for d in docs if d and str(d.get("apiVersion", "")).startswith("fogfleet.io")]
    nodes = [d for d in fog if d["kind"] == "ComputeNode"]
    rest = [d for d in fog if d["kind"] != "ComputeNode"]
    path = tmp_path / "exported.yaml"
    path.write_text(
        yaml.safe_dump_all(
            [
                {"apiVersion": "v1", "kind": "List", "items": rest, "metadata": {}},
                {"apiVersion": "fogfleet.io/v1alpha1", "kind": "ComputeNodeList", "items": nodes},
            ]
        )
    )
    direct = load_paths([LITE])
    listed = load_paths([path])
    assert set(listed.nodes) == set(direct.nodes) and len(listed.nodes) == len(nodes)
    assert set(listed.modules) == set(direct.modules)
    assert [f.metadata.name for f in listed.fleets] == [f.metadata.name for f in direct.fleets]


def test_a_list_whose_items_are_not_objects_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "list.yaml"
    path.write_text("apiVersion: v1\nkind: List\nitems: [3]\n")
    with pytest.raises(InvalidSpec) as info:
        load_paths([path])
    assert info.value.field == "items[0]"


def test_an_exponent_number_field_is_accepted(tmp_path: Path) -> None:
    text = (LITE / "modules.yaml").read_text()
    assert "cycleTimeMillis: 100\n" in text
    text = text.replace("cycleTimeMillis: 100\n", "cycleTimeMillis: 1e2\n", 1)
    (tmp_path / "modules.yaml").write_text(text)
    for f in LITE.glob("*.yaml"):
        if f.name != "modules.yaml":
            (tmp_path / f.name).write_text(f.read_text())
    catalog = load_paths([tmp_path])
    assert any(m.spec.cycle_time_millis == 100 for m in catalog.modules.values())


@pytest.mark.parametrize("codec", ["utf-16-le", "utf-16-be"])
def test_utf16_with_a_byte_order_mark_is_read_as_kubectl_reads_it(
    tmp_path: Path, codec: str
) -> None:
    # kubectl: unicode.BOMOverride(unicode.UTF8.NewDecoder()) on every file it reads
    path = tmp_path / "utf16.yaml"
    path.write_bytes(("\ufeffkind: ComputeNode\nmetadata: {name: géant}\n").encode(codec))
    assert read_documents(path) == [{"kind": "ComputeNode", "metadata": {"name": "géant"}}]


def test_broken_utf16_names_the_file_the_encoding_and_the_line(tmp_path: Path) -> None:
    path = tmp_path / "utf16.yaml"
    path.write_bytes("\ufeffa: 1\nb: 2\n".encode("utf-16-le") + b"\x00\xdc")  # a lone surrogate
    with pytest.raises(InvalidSpec) as info:
        read_documents(path)
    assert info.value.obj == str(path)
    assert "not UTF-16 LE" in info.value.message and "line 3" in info.value.message
    assert "UTF-8 only" not in info.value.message  # kubectl reads UTF-16 with a BOM too


def test_json_indented_with_tabs_is_read(tmp_path: Path) -> None:
    path = tmp_path / "node.json"
    path.write_text('{\n\t"kind": "ComputeNode",\n\t"spec": {"cpu": 1e3, "path": "a\\/b"}\n}\n')
    want = {"kind": "ComputeNode", "spec": {"cpu": 1000.0, "path": "a/b"}}
    assert read_documents(path) == [want]


def test_a_json_stream_of_objects_is_every_object(tmp_path: Path) -> None:
    path = tmp_path / "two.json"
    path.write_text('{"a": 1}\n{"b": 2}')
    assert read_documents(path) == [{"a": 1}, {"b": 2}]


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('{"a": 1,\n "a": 2}', "duplicate key 'a'"),
        ('{"a": NaN}', "NaN is not a JSON number"),
        ('{"a": 1,\n "b": }', "not valid JSON"),
    ],
)
def test_bad_json_is_refused_naming_the_file(tmp_path: Path, text: str, why: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InvalidSpec) as info:
        read_documents(path)
    assert info.value.obj == str(path) and why in info.value.message
