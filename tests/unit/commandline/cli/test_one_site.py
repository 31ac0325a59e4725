"""A folder of several fleets is one site for every command (issue 45 item 2): ``plan``,
``render``, ``simulate`` and ``explain`` give every instance the same node and the same CPU,
and none of them puts more CPU on a node than it has.

The property test builds random folders from the warehouse example's pieces: its nodes (the
edges' capacity drawn small, so the fleets contend for them), its modules copied into each
fleet's namespace, and two or three fleets of one robot each over shared edges, with names
drawn from a tiny alphabet so that two fleets of one name in two namespaces come up (``--fleet
NAMESPACE/NAME`` tells them apart). The planner's budget is tiny: agreement does not need a
good plan, only one plan.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from fogfleet.api.labels import LABEL_FLEET
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.commandline.cli import main
from fogfleet.render.deployments import identity_of

WAREHOUSE = Path(__file__).resolve().parents[4] / "manifests" / "examples" / "warehouse"
NODES = [d for d in yaml.safe_load_all((WAREHOUSE / "nodes.yaml").read_text()) if d]
MODULES = [d for d in yaml.safe_load_all((WAREHOUSE / "modules.yaml").read_text()) if d]
ROBOTS = [n["metadata"]["name"] for n in NODES if n["spec"]["tier"] == "robot"]
EDGES = [n["metadata"]["name"] for n in NODES if n["spec"]["tier"] == "edge"]
MODULE_NAMES = [m["metadata"]["name"] for m in MODULES]
# the modules that can run off their robot (the others add nothing shared to contend for)
SHAREABLE = ["nav-motion-planning", "scene-segmentation", "object-pose-estimation"]

Key = tuple[str, str, str, int]  # (fleet namespace/name, robot, module, replica)
Where = dict[Key, tuple[str, float]]  # -> (node, cpu)


@st.composite
def sites(draw: st.DrawFn) -> dict[str, Any]:
    """A folder's objects: the nodes (edge CPU drawn), and two or three fleets."""
    count = draw(st.integers(2, 3))
    keys = draw(
        st.lists(
            st.tuples(
                st.sampled_from(["warehouse", "north"]),
                st.text(alphabet="ab", min_size=1, max_size=2),
            ),
            min_size=count,
            max_size=count,
            unique=True,
        )
    )
    robots = draw(st.permutations(ROBOTS))
    fleets = [
        {
            "namespace": ns,
            "name": name,
            "robot": robots[k],
            "edges": draw(
                st.lists(st.sampled_from(EDGES[:3]), min_size=1, max_size=2, unique=True)
            ),
            "modules": draw(
                st.lists(st.sampled_from(SHAREABLE), min_size=1, max_size=3, unique=True)
            ),
            "seed": draw(st.integers(1, 3)),
        }
        for k, (ns, name) in enumerate(keys)
    ]
    edge_cpu = {e: draw(st.sampled_from([3, 5, 9])) for e in EDGES[:3]}
    return {"fleets": fleets, "edge_cpu": edge_cpu}


def write_site(site: dict[str, Any], folder: Path) -> None:
    """The site's objects as a folder of JSON files (kubectl reads them as it reads YAML; a
    JSON stream costs the loader a fraction of YAML's CPU): the nodes the fleets use, the
    modules in each fleet's namespace, the fleets."""
    used = {f["robot"] for f in site["fleets"]} | set(site["edge_cpu"])
    nodes = []
    for node in NODES:
        if node["metadata"]["name"] not in used:
            continue
        node = json.loads(json.dumps(node))
        cpu = site["edge_cpu"].get(node["metadata"]["name"])
        if cpu is not None:
            node["spec"]["capacity"]["cpu"] = cpu
        nodes.append(node)
    _write(folder / "nodes.json", nodes)
    for ns in sorted({f["namespace"] for f in site["fleets"]}):
        modules = [
            {**m, "metadata": {**m["metadata"], "namespace": ns}}
            for m in MODULES
            if m["metadata"]["name"] in SHAREABLE
        ]
        _write(folder / f"modules-{ns}.json", modules)
    fleets = [
        {
            "apiVersion": "fogfleet.io/v1alpha1",
            "kind": "RobotFleet",
            "metadata": {"name": f["name"], "namespace": f["namespace"]},
            "spec": {
                "robots": [f["robot"]],
                "nodes": f["edges"],
                "modules": [{"name": m} for m in f["modules"]],
                "scheduler": {
                    "algorithm": "nsga2",
                    "seed": f["seed"],
                    "population": 4,
                    "generations": 2,
                },
            },
        }
        for f in site["fleets"]
    ]
    _write(folder / "fleets.json", fleets)


def _write(path: Path, objects: list[dict[str, Any]]) -> None:
    path.write_text("\n".join(json.dumps(o) for o in objects))


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def _key(fleet: str, robot: str | None, module: str, replica: int | None) -> Key:
    return (fleet, "" if robot in (None, "-") else str(robot), module, int(replica or 0))


def planned(capsys: pytest.CaptureFixture[str], folder: Path) -> Where:
    _, out, _ = run(capsys, "plan", str(folder), "--json")
    docs = json.loads(out)
    return {
        _key(d["fleet"], r["robot"], r["module"], r["replica"]): (r["node"], r["cpu"])
        for d in (docs if isinstance(docs, list) else [docs])
        for r in d["placement"]
        if r["node"] is not None
    }


def rendered(capsys: pytest.CaptureFixture[str], folder: Path, names: dict[str, str]) -> Where:
    _, out, _ = run(capsys, "render", str(folder), "--allow-unplaced")
    where: Where = {}
    for dep in yaml.load_all(out, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
        ident = identity_of(dep) if dep and dep["kind"] == "Deployment" else None
        if ident is None:
            continue
        meta = dep["metadata"]
        fleet = names[f"{meta['namespace']}/{meta['labels'][LABEL_FLEET]}"]
        pod = dep["spec"]["template"]["spec"]
        terms = pod["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"]
        node = terms["nodeSelectorTerms"][0]["matchExpressions"][0]["values"][0]
        cpu = sum(parse_cpu(c["resources"]["requests"]["cpu"]) for c in pod["containers"])
        where[_key(fleet, *ident)] = (node, cpu)
    return where


def simulated(capsys: pytest.CaptureFixture[str], folder: Path, fleets: list[str]) -> Where:
    _, out, _ = run(capsys, "simulate", str(folder), "--json", "--duration", "1")
    doc = json.loads(out)
    by_fleet = doc if len(fleets) > 1 else {fleets[0]: doc}
    return {
        _key(fleet, r["robot"], r["module"], r["replica"]): (r["node"], r["cpu"])
        for fleet, result in by_fleet.items()
        for r in result["nsga2"]["placement"]
        if r["node"] is not None
    }


def explained(capsys: pytest.CaptureFixture[str], folder: Path, site: dict[str, Any]) -> Where:
    where: Where = {}
    for f in site["fleets"]:
        fleet = f"{f['namespace']}/{f['name']}"
        for module in f["modules"]:
            _, out, _ = run(
                capsys, "explain", str(folder), "--fleet", fleet, "--module", module, "-o", "json"
            )
            for inst in json.loads(out)["instances"]:
                if inst["node"] is not None:
                    key = _key(fleet, inst["robot"], module, inst["replica"])
                    where[key] = (inst["node"], inst["cpu"])
    return where


def usable_cpu(site: dict[str, Any]) -> dict[str, float]:
    """Each node's CPU to plan: capacity less its reserve."""
    out = {}
    for node in NODES:
        name = node["metadata"]["name"]
        cap = site["edge_cpu"].get(name, node["spec"]["capacity"]["cpu"])
        out[name] = parse_cpu(cap) - parse_cpu(node["spec"].get("reserved", {}).get("cpu", 0))
    return out


def overloaded(where: Where, usable: dict[str, float]) -> dict[str, float]:
    load: dict[str, float] = {}
    for node, cpu in where.values():
        load[node] = load.get(node, 0.0) + cpu
    return {n: c for n, c in load.items() if c > usable[n] + 1e-6}


def _rounded(where: Where) -> dict[Key, tuple[str, float]]:
    return {k: (node, round(cpu, 6)) for k, (node, cpu) in where.items()}


@pytest.fixture
def folders(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    yield lambda: tmp_path_factory.mktemp("site")


# no shrinking: each example plans a site a dozen times, and a failure shrunk costs minutes of
# CPU; the failing example is printed as drawn
@settings(
    max_examples=3,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    phases=(Phase.explicit, Phase.reuse, Phase.generate),
)
@given(site=sites())
def test_every_command_gives_each_instance_the_plans_node_and_cpu(
    site: dict[str, Any], capsys: pytest.CaptureFixture[str], folders: Any
) -> None:
    folder = folders()
    write_site(site, folder)
    fleets = [f"{f['namespace']}/{f['name']}" for f in site["fleets"]]
    names = {
        f"{f['namespace']}/{label_value(f['name'])}": n
        for f, n in zip(site["fleets"], fleets, strict=True)
    }
    plan = planned(capsys, folder)
    usable = usable_cpu(site)
    assert not overloaded(plan, usable)
    for command, where in (
        ("render", rendered(capsys, folder, names)),
        ("simulate", simulated(capsys, folder, fleets)),
        ("explain", explained(capsys, folder, site)),
    ):
        assert _rounded(where) == _rounded(plan), command
        assert not overloaded(where, usable), command


def _contended(folder: Path) -> Path:
    """Two fleets named ``warehouse`` in two namespaces, each with one small robot (1 core to
    give) and two 4-core modules, over one edge of 8.5 cores: the first fleet takes the edge."""
    site = {
        "fleets": [
            {
                "namespace": ns,
                "name": "warehouse",
                "robot": robot,
                "edges": ["edge-1"],
                "modules": ["scene-segmentation", "object-pose-estimation"],
                "seed": 1,
            }
            for ns, robot in (("warehouse", "robot-1"), ("north", "robot-2"))
        ],
        "edge_cpu": {"edge-1": 9},
    }
    write_site(site, folder)
    nodes = [json.loads(line) for line in (folder / "nodes.json").read_text().splitlines()]
    for node in nodes:
        if node["spec"]["tier"] == "robot":
            node["spec"]["capacity"]["cpu"] = 3  # 2 of them reserved
    _write(folder / "nodes.json", nodes)
    return folder


def test_a_fleet_refused_for_the_room_others_hold_is_told_who_holds_how_many_cores(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    folder = _contended(tmp_path)
    for command in ("plan", "render"):
        code, _, err = run(capsys, command, str(folder), "--fleet", "north/warehouse")
        assert code == 2, command
        assert "RobotFleet warehouse/warehouse 8 cores" in err, command
        assert "edge-1 has 0.5 of 8.5 cores left" in err, command
    code, out, _ = run(capsys, "render", str(folder), "--fleet", "warehouse/warehouse")
    assert code == 0 and "north" not in out  # the first fleet is not held back by the second
    # validate refuses the folder with plan's refusal, naming the fleet
    code, out, err = run(capsys, "validate", str(folder))
    assert code == 2 and out == ""
    assert "error: RobotFleet/north/warehouse" in err
    assert "RobotFleet warehouse/warehouse 8 cores" in err
    assert "edge-1 has 0.5 of 8.5 cores left" in err


def test_fleets_of_one_name_in_two_namespaces_are_told_apart(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    folder = _contended(tmp_path)
    for fleet in ([], ["--fleet", "warehouse"]):
        code, _, err = run(capsys, "explain", str(folder), *fleet, "--module", "scene-segmentation")
        assert code == 2 and "warehouse/warehouse, north/warehouse" in err
        assert "NAMESPACE/NAME" in err
    code, out, _ = run(
        capsys,
        "explain",
        str(folder),
        "--fleet",
        "warehouse/warehouse",
        "--module",
        "scene-segmentation",
        "-o",
        "json",
    )
    assert code == 0 and json.loads(out)["fleet"] == "warehouse/warehouse"
