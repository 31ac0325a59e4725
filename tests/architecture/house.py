"""The shape of the operator package, for reviews: files and lines per folder, import arrows
between folders, the longest functions, and the path of one reconcile.

    python tests/architecture/house.py [TREE]     # TREE: a checkout (default: this one)

"One reconcile" is a full pass of the warehouse fleet against the controller tests' in-memory
cluster (tests/unit/controllers/conftest.py), traced: the fogfleet functions it runs
("places"), the files they live in, the distinct calls that cross from one folder to another,
and how often a call climbs up the layers (a callee in a higher layer of ``.importlinter``'s
layers contract than its caller: a callback).
"""

from __future__ import annotations

import argparse
import ast
import configparser
import importlib
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any


def layers(tree: Path) -> list[set[str]]:
    """The layers contract of the tree's .importlinter, top first: the folders of each."""
    config = configparser.ConfigParser()
    config.read(tree / ".importlinter")
    lines = config["importlinter:contract:layers"]["layers"].split("\n")
    return [
        {m.strip().removeprefix("fogfleet.") for m in line.split("|")} for line in lines if line
    ]


def rank(folder: str, order: list[set[str]]) -> int:
    """A folder's layer, higher further up (0: the package's own top-level modules)."""
    for i, layer in enumerate(order):
        if folder in layer:
            return len(order) - i
    return 0


def folder_of(path: Path, package: Path) -> str:
    parts = path.relative_to(package).parts
    return parts[0] if len(parts) > 1 else path.stem


def room_of(path: Path, package: Path) -> str:
    """``controllers/fleet`` for a file in a room of a folder, else the folder."""
    parts = path.relative_to(package).parts
    return "/".join(parts[:2]) if len(parts) > 2 else folder_of(path, package)


def folders(package: Path) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for path in sorted(package.rglob("*.py")):
        f = folder_of(path, package)
        row = out.setdefault(f if (package / f).is_dir() else "(top)", {"files": 0, "lines": 0})
        row["files"] += 1
        row["lines"] += len(path.read_text().splitlines())
    return out


def arrows(package: Path) -> dict[str, int]:
    """Import statements (also inside functions) from one folder to another."""
    found: Counter[str] = Counter()
    for path in package.rglob("*.py"):
        src = folder_of(path, package)
        for node in ast.walk(ast.parse(path.read_text())):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                parts = name.split(".")
                if parts[0] == "fogfleet" and len(parts) > 1 and parts[1] != src:
                    found[f"{src} -> {parts[1]}"] += 1
    return dict(sorted(found.items()))


def rooms(package: Path, folder: str) -> dict[str, Any]:
    """Inside one folder (``controllers``, ``runtime``): files and lines per room (its
    sub-folders; ``(top)`` for its own modules) and the import arrows between its rooms."""
    base = package / folder
    if not base.is_dir():
        return {}
    sizes: dict[str, dict[str, int]] = {}
    found: Counter[str] = Counter()
    for path in sorted(base.rglob("*.py")):
        src = folder_of(path, base) if len(path.relative_to(base).parts) > 1 else "(top)"
        row = sizes.setdefault(src, {"files": 0, "lines": 0})
        row["files"] += 1
        row["lines"] += len(path.read_text().splitlines())
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                parts = node.module.split(".")
                if parts[:2] != ["fogfleet", folder] or len(parts) < 3:
                    continue
                dst = parts[2] if (base / parts[2]).is_dir() else "(top)"
                if dst != src:
                    found[f"{src} -> {dst}"] += 1
    return {"rooms": sizes, "arrows": dict(sorted(found.items()))}


def longest(package: Path, n: int = 5) -> list[tuple[int, str]]:
    rows = []
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                assert node.end_lineno is not None
                where = f"{path.relative_to(package)}:{node.name}"
                rows.append((node.end_lineno - node.lineno + 1, where))
    return sorted(rows, reverse=True)[:n]


def trace_reconcile(tree: Path, package: Path) -> dict[str, Any]:
    sys.path[:0] = [str(tree / "operator"), str(tree / "tests" / "unit" / "controllers")]
    conftest = importlib.import_module("conftest")
    deps_module = importlib.import_module("fogfleet.controllers.deps")
    reconcile = importlib.import_module("fogfleet.controllers.fleet.reconcile").reconcile
    kube = conftest.FakeKube()
    kube.load_warehouse()
    deps = deps_module.Deps(kube=kube, planner=conftest.CountingPlanner())
    body = kube.get_fleet("warehouse", "warehouse")
    order = layers(tree)
    places: set[tuple[str, str]] = set()
    crossings: set[tuple[tuple[str, str], tuple[str, str]]] = set()
    climbs = 0
    root = str(package)

    def where(frame: Any) -> tuple[str, str] | None:
        file = frame.f_code.co_filename
        if not file.startswith(root) or frame.f_code.co_name.startswith("<"):
            return None
        return file, frame.f_code.co_name

    def profile(frame: Any, event: str, _: Any) -> None:
        nonlocal climbs
        if event != "call":
            return
        callee = where(frame)
        if callee is None:
            return
        places.add(callee)
        caller = frame.f_back
        while caller is not None and where(caller) is None:
            caller = caller.f_back
        if caller is not None:
            up = rank(folder_of(Path(callee[0]), package), order)
            down = rank(folder_of(Path(caller.f_code.co_filename), package), order)
            climbs += up > down
            source = where(caller)
            assert source is not None
            if folder_of(Path(source[0]), package) != folder_of(Path(callee[0]), package):
                crossings.add((source, callee))

    sys.setprofile(profile)
    try:
        reconcile(body, deps)
    finally:
        sys.setprofile(None)
    files = {f for f, _ in places}
    by_folder = Counter(room_of(Path(f), package) for f, _ in places)
    return {
        "places": len(places),
        "files": len(files),
        "places_by_room": dict(sorted(by_folder.items())),
        "folder_crossings": len(crossings),  # distinct caller -> callee pairs across folders
        "climbs": climbs,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree", nargs="?", default=str(Path(__file__).resolve().parents[2]))
    tree = Path(parser.parse_args().tree).resolve()
    package = tree / "operator" / "fogfleet"
    report = {
        "folders": folders(package),
        "arrows": arrows(package),
        "rooms": {f: rooms(package, f) for f in ("controllers", "runtime")},
        "longest": longest(package),
        "reconcile": trace_reconcile(tree, package),
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
