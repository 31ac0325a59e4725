"""No import cycle between the modules of ``fogfleet`` or of ``e2e`` (the bed, its tests and
benchmarks), counting the imports that hide one: those
inside functions and under ``TYPE_CHECKING`` (STYLE.md: an import inside a function to dodge a
cycle is still a cycle; move the shared piece down a layer).

The graph is grimp's (import-linter's engine), which parses every module and records every
import statement wherever it stands; the second test holds it to that.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

import grimp
import pytest


def strongly_connected(graph: Mapping[str, set[str]]) -> Iterator[list[str]]:
    """The components of more than one module (Tarjan, iterative: no recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        component.append(m)
                        if m == node:
                            break
                    if len(component) > 1:
                        yield sorted(component)


def import_graph(package: str) -> dict[str, set[str]]:
    g = grimp.build_graph(package, cache_dir=None)
    return {m: set(g.find_modules_directly_imported_by(m)) & g.modules for m in g.modules}


REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("package", ["fogfleet", "e2e"])
def test_no_module_imports_itself_round_a_cycle(
    package: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.syspath_prepend(str(REPO))  # e2e is a package of the checkout, not installed
    cycles = list(strongly_connected(import_graph(package)))
    assert not cycles, "import cycles (modules of each):\n" + "\n".join(
        "  " + " <-> ".join(c) for c in cycles
    )


def test_the_graph_counts_imports_inside_functions_and_under_type_checking(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pkg = tmp_path / "cycleprobe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from . import b\n    return b\n")
    (pkg / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import c\n"
    )
    (pkg / "c.py").write_text("from . import a\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        cycles = list(strongly_connected(import_graph("cycleprobe")))
    finally:
        for name in [m for m in sys.modules if m.startswith("cycleprobe")]:
            del sys.modules[name]
    assert cycles == [["cycleprobe.a", "cycleprobe.b", "cycleprobe.c"]]
