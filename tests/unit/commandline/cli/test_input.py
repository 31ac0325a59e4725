"""Input read as kubectl reads it (issue 45): JSON files in folders, objects of a misspelt group
named where a fleet misses them, every error of every object and fleet at once, and exit 2
for bad input from every command."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from fogfleet.commandline.cli import main

REPO = Path(__file__).resolve().parents[4]
LITE = REPO / "manifests" / "examples" / "warehouse-lite"


def _docs(name: str) -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all((LITE / name).read_text()) if d]


def _copy(tmp_path: Path, *skip: str) -> Path:
    for f in LITE.glob("*.yaml"):
        if f.name not in skip:
            (tmp_path / f.name).write_text(f.read_text())
    return tmp_path


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# 1. a folder's .json files are read beside its .yaml files -----------------------------------


def test_json_files_in_a_folder_are_read_one_object_or_a_list(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(tmp_path, "nodes.yaml", "fleet.yaml")
    nodes = _docs("nodes.yaml")
    (folder / "nodes.json").write_text(json.dumps({"kind": "List", "items": nodes}, indent="\t"))
    (folder / "fleet.json").write_text(json.dumps(_docs("fleet.yaml")[0]))
    code, out, err = _run(capsys, "validate", str(folder))
    assert code == 0, err
    assert out.startswith(f"OK: {len(nodes)} ComputeNode") and "1 RobotFleet" in out


def test_a_bad_json_file_in_a_folder_is_an_error_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (_copy(tmp_path) / "extra.json").write_text('{"kind": "ComputeNode",}')
    code, _, err = _run(capsys, "validate", str(tmp_path))
    assert code == 2 and "extra.json" in err and "not valid JSON" in err


@pytest.mark.parametrize("content", [{}, {"00-namespace.yaml": "apiVersion: v1\nkind: Namespace"}])
def test_validate_of_input_without_fogfleet_objects_exits_2(
    tmp_path: Path, content: dict[str, str], capsys: pytest.CaptureFixture[str]
) -> None:
    for name, text in content.items():
        (tmp_path / name).write_text(text)
    code, out, err = _run(capsys, "validate", str(tmp_path))
    assert code == 2 and out == ""
    assert "no ComputeNode, SoftwareModule or RobotFleet found" in err


def test_validate_names_every_missing_path_and_reads_the_others(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "broken.yaml"
    bad.write_text("- not an object\n")
    code, _, err = _run(capsys, "validate", "no-such-1", str(LITE), "no-such-2", str(bad))
    assert code == 2
    assert "error: no-such-1: no such file" in err and "error: no-such-2: no such file" in err
    assert f"error: {bad}: document 1: is a list, not an object" in err
    assert "3 error(s)" in err


# 3. an object of a misspelt group is named where a fleet misses it ---------------------------


def _misspelt(tmp_path: Path) -> tuple[Path, str]:
    folder = _copy(tmp_path, "nodes.yaml")
    nodes = _docs("nodes.yaml")
    nodes[0]["apiVersion"] = "fogflet.io/v1alpha1"
    (folder / "nodes.yaml").write_text(yaml.safe_dump_all(nodes))
    return folder, nodes[0]["metadata"]["name"]


def test_a_reference_to_an_object_of_a_misspelt_group_names_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, name = _misspelt(tmp_path)
    for argv in (["validate", str(folder)], ["plan", str(folder), "--scheduler", "onboard"]):
        code, _, err = _run(capsys, *argv)
        assert code == 2
        assert f"ComputeNode {name!r} does not exist" in err
        assert (
            f"nodes.yaml defines ComputeNode/{name}, skipped: apiVersion fogflet.io/v1alpha1 is "
            "not fogfleet's (it reads fogfleet.io/v1alpha1)"
        ) in err


def test_validate_lists_skipped_objects_of_other_groups(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, name = _misspelt(tmp_path)
    _, _, err = _run(capsys, "validate", str(folder))
    assert f"skipped: ComputeNode/{name} in {folder / 'nodes.yaml'}: apiVersion fogflet.io" in err
    assert "skipped: Namespace/" in err


# 4. every error of every object, every bad reference of every fleet --------------------------


def test_validate_lists_every_bad_field_of_every_object(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(tmp_path, "nodes.yaml")
    nodes = _docs("nodes.yaml")
    nodes[0]["spec"]["tier"] = "moon"
    nodes[0]["spec"]["bogus"] = 1
    nodes[1]["spec"]["capacity"]["cpu"] = "lots"
    (folder / "nodes.yaml").write_text(yaml.safe_dump_all(nodes))
    code, _, err = _run(capsys, "validate", str(folder))
    assert code == 2
    first, second = (f"ComputeNode/{n['metadata']['name']}" for n in nodes[:2])
    where = f"(in {folder / 'nodes.yaml'})"
    assert f"{first}: spec.tier: " in err and f"{first}: spec.bogus: unknown field {where}" in err
    assert f"{second}: spec.capacity.cpu: 'lots' is not a Kubernetes quantity" in err


def test_validate_lists_every_bad_reference_of_every_fleet(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(tmp_path, "fleet.yaml")
    fleet = _docs("fleet.yaml")[0]
    fleet["spec"]["robots"] += ["ghost-1", "ghost-2"]
    fleet["spec"]["modules"].append({"name": "ghost-module"})
    other = json.loads(json.dumps(fleet))
    other["metadata"]["name"] = "second"
    other["spec"]["nodes"] = ["ghost-edge"]
    (folder / "fleet.yaml").write_text(yaml.safe_dump_all([fleet, other]))
    code, _, err = _run(capsys, "validate", str(folder))
    assert code == 2
    for obj in (f"RobotFleet/{fleet['metadata']['name']}", "RobotFleet/second"):
        assert f"{obj}: spec.robots[" in err and "'ghost-1' does not exist" in err
        assert err.count(f"{obj}: spec.robots[") == 2
        assert f"{obj}: spec.modules[" in err and "ghost-module does not exist" in err
    assert "RobotFleet/second: spec.nodes[0]: ComputeNode 'ghost-edge' does not exist" in err
    assert "7 error(s)" in err


def test_validate_lists_every_node_without_room_and_every_bad_cycle_of_a_fleet(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(tmp_path, "nodes.yaml", "fleet.yaml")
    nodes = _docs("nodes.yaml")
    for node in nodes[:2]:
        node["spec"]["reserved"] = {"cpu": node["spec"]["capacity"]["cpu"]}
    del nodes[2]["spec"]["capacity"]
    (folder / "nodes.yaml").write_text(yaml.safe_dump_all(nodes))
    fleet = _docs("fleet.yaml")[0]
    for ref in fleet["spec"]["modules"][:2]:
        ref["overrides"] = {"cycleTimeMillis": 0}
    other = {**fleet, "metadata": {**fleet["metadata"], "name": "second"}}
    (folder / "fleet.yaml").write_text(yaml.safe_dump_all([fleet, other]))
    code, _, err = _run(capsys, "validate", str(folder))
    assert code == 2
    for node in nodes[:2]:  # once, though both fleets use them
        assert err.count(f"ComputeNode/{node['metadata']['name']}: spec.reserved.cpu: ") == 1
    assert f"ComputeNode/{nodes[2]['metadata']['name']}: spec.capacity: required" in err
    for name in (fleet["metadata"]["name"], "second"):
        for k in (0, 1):
            assert f"RobotFleet/{name}: spec.modules[{k}].overrides.cycleTimeMillis: " in err
    assert "7 error(s)" in err


# 5. bad input exits 2 from every command -----------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["explain", str(LITE), "--module", "no-such-module", "--scheduler", "onboard"],
        ["plan", str(LITE), "--population", "3"],
        ["render", str(LITE), "--scheduler", "onboard", "--generations", "0"],
        ["simulate", str(LITE), "--scheduler", "onboard", "--seed", "-1"],
        ["validate", str(LITE / "no-such-file.yaml")],
    ],
)
def test_bad_input_exits_2_naming_what_is_wrong(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = _run(capsys, *argv)
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err


def test_explain_of_two_fleets_without_fleet_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(tmp_path, "fleet.yaml")
    fleet = _docs("fleet.yaml")[0]
    other = {**fleet, "metadata": {**fleet["metadata"], "name": "second"}}
    (folder / "fleet.yaml").write_text(yaml.safe_dump_all([fleet, other]))
    code, _, err = _run(capsys, "explain", str(folder), "--module", "x")
    assert code == 2 and "--fleet" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", str(LITE), "--duration", "-5"],
        ["plan", str(LITE), "--time-budget", "0"],
        ["explain", str(LITE), "--module", "x", "--limit", "0"],
    ],
)
def test_an_option_out_of_range_exits_2(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as info:  # argparse, naming the option
        main(argv)
    assert info.value.code == 2
    assert "must be greater than zero" in capsys.readouterr().err


@pytest.mark.parametrize(
    "saved", [{"a": 1}, _docs("fleet.yaml")[0], {"status": {"observedGeneration": 1}}]
)
def test_simulate_of_a_placement_file_without_a_placement_exits_2(
    saved: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "saved.json"
    path.write_text(json.dumps(saved))
    argv = ["simulate", str(LITE), "--scheduler", "onboard", "--duration", "1"]
    code, _, err = _run(capsys, *argv, "--placement", str(path))
    assert code == 2, "it simulated every module UNPLACED and exited 0"
    assert f"error: {path}: placement: " in err
