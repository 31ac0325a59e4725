"""`kubectl apply -f <example dir>/` applies files in name order: the Namespace must come first."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

EXAMPLES = Path(__file__).resolve().parents[2] / "manifests" / "examples"


def _docs(example: Path) -> list[tuple[str, dict[str, Any]]]:
    return [
        (path.name, doc)
        for path in sorted(example.glob("*.yaml"))  # kubectl's order
        for doc in yaml.safe_load_all(path.read_text())
        if doc and "kind" in doc
    ]


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.iterdir() if p.is_dir()))
def test_an_example_creates_its_namespace_before_anything_uses_it(example: str) -> None:
    docs = _docs(EXAMPLES / example)
    own = {d["metadata"]["name"] for _, d in docs if d["kind"] == "Namespace"}
    created: set[str] = set()
    for name, doc in docs:
        if doc["kind"] == "Namespace":
            created.add(doc["metadata"]["name"])
        ns = doc.get("metadata", {}).get("namespace")
        if ns in own:
            assert ns in created, f"{example}/{name} uses namespace {ns} before it is created"
