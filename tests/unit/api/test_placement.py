"""The compact placement of a large fleet's status (issue 46): the same facts as the list, in a
few bytes per instance, read back by one function whichever form a status has."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from fogfleet.api.v1alpha1.placement import CompactPlacement, placement_entries_of


def _entries(robots: int, modules: int = 8, edges: int = 100) -> list[dict]:
    """A 1000-robot fleet's entries as the operator writes them: per-robot modules on their
    robot or an edge, and one shared module's replicas."""
    out: list[dict] = []
    for r in range(robots):
        for m in range(modules):
            on_edge = (r + m) % 3 == 0
            out.append(
                {
                    "robot": f"robot-{r:04d}",
                    "module": f"module-{m}",
                    "node": f"edge-{(r * 7 + m) % edges:03d}" if on_edge else f"robot-{r:04d}",
                    "tier": "edge" if on_edge else "robot",
                    "cpu": f"{100 + 25 * m}m",
                }
            )
    for k in range(3):
        shared = {"robot": "", "module": "detector", "node": "cloud-1", "tier": "cloud"}
        out.append({**shared, "cpu": "1500m", "replica": k})
    return out


def _key(e: dict) -> tuple:
    return (e["robot"], e["module"], e.get("replica", 0))


def test_the_compact_form_gives_back_every_entry() -> None:
    entries = _entries(40)
    compact = CompactPlacement.of(entries)
    back = CompactPlacement.model_validate(json.loads(json.dumps(compact.wire()))).entries()
    assert sorted(back, key=_key) == sorted(entries, key=_key)


def test_a_thousand_robots_fit_in_a_few_bytes_per_instance() -> None:
    """What made the list unusable above 1000 instances: ~110 bytes each (0.9 MiB at 8000)."""
    entries = _entries(1000)
    listed = len(json.dumps(entries, separators=(",", ":")))  # as the API server stores JSON
    compact = len(json.dumps(CompactPlacement.of(entries).wire(), separators=(",", ":")))
    assert compact / len(entries) < 20, compact / len(entries)
    assert compact < listed / 5


def test_either_form_is_read_the_list_first() -> None:
    entries = _entries(2)
    compact = CompactPlacement.of(entries).wire()
    assert placement_entries_of({"placement": entries[:1], "placementCompact": compact}) == [
        entries[0]
    ]
    read = placement_entries_of({"placement": [], "placementCompact": compact})
    assert sorted(read, key=_key) == sorted(entries, key=_key)
    assert placement_entries_of({}) == []
    broken = {**compact, "tiers": compact["tiers"][:-1]}  # not what this operator writes
    assert placement_entries_of({"placementCompact": broken}) == []


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda c: c["modules"][0]["node"].pop(), "one value per instance"),
        (lambda c: c["modules"][0]["node"].__setitem__(0, 99), "node index outside nodes"),
        (lambda c: c["modules"][0]["robot"].__setitem__(0, 5), "robot index outside robots"),
        (lambda c: c["tiers"].pop(), "3 nodes but 2 tiers"),
    ],
)
def test_a_malformed_compact_form_is_refused_with_the_reason(change, words: str) -> None:
    wire = CompactPlacement.of(_entries(1, modules=2, edges=1)).wire()
    change(wire)
    with pytest.raises(ValidationError, match=words):
        CompactPlacement.model_validate(wire)
