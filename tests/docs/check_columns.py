"""The docs' ``kubectl get`` columns against the CRDs' printer columns (``make docs-check``).

A column a page names must be one ``kubectl get`` prints for that kind, read from the
generated CRDs in ``crds/`` (``additionalPrinterColumns``; ``-o wide`` adds those of priority
1). Two ways of naming columns are checked, both in capitals as kubectl prints them:

* a command's comment in a code block::

      kubectl get robotfleets -n warehouse   # READY, PLACED, SPLIT, MISS

* code spans in the same paragraph or list item as a ``kubectl get KIND`` code span:
  "`kubectl get computenodes` ... `-o wide` adds `FLEETS`". A paragraph that says ``-o wide``
  may name the wide columns too.

Only fogfleet's kinds are checked (by plural, singular, short name or ``plural.group``);
``NAME`` and ``NAMESPACE`` are always columns.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import yaml

__all__ = ["Kind", "check_columns", "kinds_in"]

ALWAYS = frozenset({"NAME", "NAMESPACE"})
FENCE = re.compile(r"^\s*(```+|~~~+)")
CODE_SPAN = re.compile(r"(`+)(.+?)(?<!`)\1(?!`)", re.S)
CAPS = re.compile(r"^[A-Z][A-Z0-9_-]+$")
GET = re.compile(r"\bkubectl\s+get\s+([a-z][a-z0-9.-]*)((?:\s+\S+)*)")
WIDE = re.compile(r"(?:-o\s*|--output[=\s])wide\b")
ITEM = re.compile(r"^\s*(?:[-*+]|\d+[.)])\s")


@dataclass(frozen=True)
class Kind:
    name: str
    columns: frozenset[str]  # what `kubectl get` prints
    wide: frozenset[str]  # ... with -o wide


def kinds_in(root: Path) -> dict[str, Kind]:
    """Resource name (plural, singular, short names, plural.group) -> the kind's columns, from
    the CRDs in ``root/crds`` (none: nothing to check against)."""
    out: dict[str, Kind] = {}
    for path in sorted((root / "crds").glob("*.yaml")):
        for crd in yaml.safe_load_all(path.read_text(encoding="utf-8")):
            if not isinstance(crd, dict) or crd.get("kind") != "CustomResourceDefinition":
                continue
            spec = crd["spec"]
            names = spec["names"]
            columns = [c for v in spec["versions"] for c in v.get("additionalPrinterColumns", [])]
            plain = {c["name"].upper() for c in columns if not c.get("priority")}
            kind = Kind(
                names["kind"],
                frozenset(plain | ALWAYS),
                frozenset({c["name"].upper() for c in columns} | ALWAYS),
            )
            for alias in [
                names["plural"],
                names.get("singular", ""),
                *names.get("shortNames", []),
                f"{names['plural']}.{spec['group']}",
            ]:
                if alias:
                    out[alias] = kind
    return out


def _chunks(text: str) -> Iterator[tuple[int, str, bool]]:
    """(first line, text, is a code block line): code block lines one by one; prose by
    paragraph and list item."""
    fence: str | None = None
    prose: list[tuple[int, str]] = []

    def flush() -> Iterator[tuple[int, str, bool]]:
        if prose:
            yield prose[0][0], "\n".join(t for _, t in prose), False
            prose.clear()

    for no, line in enumerate(text.split("\n"), 1):
        m = FENCE.match(line)
        if fence is not None:
            if line.strip().startswith(fence):
                fence = None
            else:
                yield no, line, True
            continue
        if m:
            yield from flush()
            fence = m.group(1)[0] * 3
        elif not line.strip() or ITEM.match(line):
            yield from flush()
            if line.strip():
                prose.append((no, line))
        else:
            prose.append((no, line))
    yield from flush()


def _unknown(kind: Kind, named: list[str], wide: bool) -> list[str]:
    known = kind.wide if wide else kind.columns
    return [c for c in named if c not in known]


def _say(resource: str, kind: Kind, bad: list[str], wide: bool) -> str:
    shown = kind.wide if wide else kind.columns
    return (
        f"`kubectl get {resource}{' -o wide' if wide else ''}` has no column "
        f"{', '.join(bad)} (it prints {', '.join(sorted(shown - ALWAYS))})"
    )


def check_columns(text: str, kinds: dict[str, Kind]) -> Iterator[tuple[int, str]]:
    """(line, message) for every column a Markdown page names that its kind does not print."""
    if not kinds:
        return
    for line, chunk, block in _chunks(text):
        if block:
            command, _, comment = chunk.partition(" #")
            m = GET.search(command)
            named = [w.strip() for w in comment.split(",")]
            if m is None or m.group(1) not in kinds or not all(CAPS.match(w) for w in named):
                continue
            kind, wide = kinds[m.group(1)], bool(WIDE.search(command))
            bad = _unknown(kind, named, wide)
            if bad:
                yield line, _say(m.group(1), kind, bad, wide)
            continue
        spans = [" ".join(s.group(2).split()) for s in CODE_SPAN.finditer(chunk)]
        gets = [(m.group(1), m.group(2)) for s in spans if (m := GET.search(s))]
        mine = [(r, rest) for r, rest in gets if r in kinds]
        if not mine:
            continue
        named = [s for s in spans if CAPS.match(s)]
        wide = any(WIDE.search(s) for s in spans)
        known = frozenset().union(*((kinds[r].wide if wide else kinds[r].columns) for r, _ in mine))
        bad = [c for c in named if c not in known]
        if bad:
            resource = mine[0][0]
            yield line, _say(resource, kinds[resource], bad, wide)
