"""``kubectl fogfleet`` output: kubectl-style tables (upper-case headers, columns padded), or
the same document as JSON or YAML (``-o json|yaml``)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import yaml

from fogfleet.domain.miss_rates import format_miss_rate
from fogfleet.domain.takeovers import format_gap

__all__ = ["FORMATS", "diff_table", "render", "top_table", "why_table"]

FORMATS = ("table", "json", "yaml")
Doc = dict[str, Any]


def render(doc: Doc, fmt: str, table: str) -> str:
    """``doc`` as JSON or YAML, else the ``table`` made from it."""
    if fmt == "json":
        return json.dumps(doc, indent=2)
    if fmt == "yaml":
        return yaml.safe_dump(doc, sort_keys=False).rstrip()
    return table


def _rate(value: float | None) -> str:
    """A miss rate in the one format of the CLI and kubectl's MISS column (``-``: none)."""
    return format_miss_rate(value)


def _columns(rows: Sequence[Sequence[object]], indent: str = "") -> list[str]:
    widths = [max(len(str(r[k])) for r in rows) for k in range(len(rows[0]))]
    return [
        (indent + "   ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True))).rstrip()
        for r in rows
    ]


def why_table(doc: Doc) -> str:
    """Where each instance runs, then each node it could have used and why not."""
    lines = [
        f"RobotFleet {doc['fleet']}, module {doc['module']}: predicted miss rate "
        f"{_rate(doc['predictedMissRate'])}, measured {_rate(doc['measuredMissRate'])}"
    ]
    for inst in doc["instances"]:
        cpu = "-" if inst["cpu"] is None else f"{inst['cpu']:g}"
        lines.append("")
        lines += _columns(
            [
                ["INSTANCE", "NODE", "TIER", "CPU", "PREDICTED-MISS"],
                [
                    inst["instance"],
                    inst["node"] or "<none>",
                    inst["tier"] or "-",
                    cpu,
                    _rate(inst["predictedMiss"]),
                ],
            ]
        )
        alts = [[a["node"], a["tier"], a["rule"], a["reason"]] for a in inst["alternatives"]]
        if alts:
            lines += _columns(
                [["  NOT ON", "TIER", "RULE", "WHY"], *[["  " + a[0], *a[1:]] for a in alts]]
            )
        split = inst.get("split")
        if split:  # a split network: the action on this node, then the others and why not
            lines.append(f"  split: {split['reason']}")
            lines += _columns(
                [
                    ["  NOT", "WHY"],
                    *[["  " + a["action"], a["reason"]] for a in split["alternatives"]],
                ]
            )
    if doc.get("omittedInstances"):
        lines.append(f"\n({doc['omittedInstances']} more instances: pass --robot to see one)")
    return "\n".join(lines)


def top_table(doc: Doc) -> str:
    """The fleet's line, then one line per module."""
    head = _columns(
        [
            [
                "FLEET",
                "PREDICTED-MISS",
                "MEASURED-MISS",
                "CPU-REQUESTED",
                "CPU-EXPECTED",
                "SPLIT",
                "FALLBACKS-ACTIVE",
                "TAKEOVERS",
            ],
            [
                doc["fleet"],
                _rate(doc["predictedMissRate"]),
                _rate(doc["measuredMissRate"]),
                f"{doc['cpuRequested']:g}",
                f"{doc['cpuExpected']:g}",
                doc["split"],
                ",".join(f"{r}:{'+'.join(m)}" for r, m in doc["fallbacksActive"].items()) or "-",
                "-" if doc.get("takeovers") is None else doc["takeovers"],
            ],
        ]
    )
    rows = [
        [
            "MODULE",
            "INSTANCES",
            "SPLIT",
            "PREDICTED-MISS",
            "MEASURED-MISS",
            "CPU-REQUESTED",
            "CPU-EXPECTED",
            "FALLBACKS-ACTIVE",
            "LAST-TAKEOVER",
        ]
    ]
    for m in doc["modules"]:
        rows.append(
            [
                m["module"],
                m["instances"],
                m["split"],
                _rate(m["predictedMissRate"]),
                _rate(m["measuredMissRate"]),
                f"{m['cpuRequested']:g}",
                f"{m['cpuExpected']:g}",
                ",".join(m["fallbacksActive"]) or "-",
                _takeover(m.get("lastTakeover")),
            ]
        )
    return "\n".join([*head, "", *_columns(rows)])


def _takeover(last: Doc | None) -> str:
    """A module's last takeover: its gap, how long ago and where (``0.41 s, 2m ago
    (robot-2)``); ``-``: none seen."""
    if not last:
        return "-"
    gap = "gap ?" if last.get("gapSeconds") is None else format_gap(float(last["gapSeconds"]))
    return f"{gap}, {_ago(int(last['agoSeconds']))} ago ({last['robot']})"


def _ago(seconds: int) -> str:
    """An age as kubectl prints one: 45s, 2m, 3h, 2d."""
    for unit, size, limit in (("s", 1, 120), ("m", 60, 7200), ("h", 3600, 172800)):
        if seconds < limit:
            return f"{seconds // size}{unit}"
    return f"{seconds // 86400}d"


def diff_table(doc: Doc) -> str:
    """The moves, then each objective running vs planned."""
    lines = [f"RobotFleet {doc['fleet']}: a re-plan now (not applied): {doc['choiceReason']}"]
    if doc["moves"]:
        lines += [
            "",
            *_columns(
                [
                    ["INSTANCE", "FROM", "TO"],
                    *[[m["instance"], m["from"] or "<new>", m["to"]] for m in doc["moves"]],
                ]
            ),
        ]
    else:
        lines += ["", "no moves: the re-plan keeps every instance where it runs"]
    rows = [["OBJECTIVE", "RUNNING", "PLANNED", "CHANGE"]]
    rows += [
        [o["name"], f"{o['running']:.6g}", f"{o['planned']:.6g}", f"{o['change']:+.4g}"]
        for o in doc["objectives"]
    ]
    return "\n".join([*lines, "", *_columns(rows)])
