"""The split benchmark's table and docs page, from its record (``bench-split.json``).

python -m e2e.bench.split.report --json bench-split.json --docs docs/benchmarks/split.md
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.bench.split.protocol import ARMS, GAMMA_MS, LINKS, TARGET_REDUCTION, WHOLE_ROBOT
from fogfleet.bench.record import page, read_record

__all__ = ["main", "table"]

SUITE = "split"
ABOUT = (
    "A split network (issue 48) against the two whole-module placements of the same network "
    "on the bed's real nodes and emulated link (`e2e/bench/split/protocol.py` fixes the "
    "protocol). Frames over alpha: of the camera's frames in a window, those not answered "
    "within maxLatencyMillis (100 ms). Medians over the runs; the runs' own values in "
    "brackets. Robot ms: the CPU time of the robot's head thread per answered frame (what "
    f"maxRobotMillis, {GAMMA_MS:g} ms here, bounds); frame ms: the mean frame, capture to answer."
)


def _num(x: Any, fmt: str = "{:.3g}") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return fmt.format(x)


def table(result: Mapping[str, Any]) -> str:
    """Per link and arm the medians, then the verdict at the slow link."""
    summ: Mapping[str, Mapping[str, Any]] = result["summary"]
    frames = round(result["protocol"]["windowSeconds"] * 1000 / result["protocol"]["cycleMillis"])
    head = ["link", "arm", f"over alpha of {frames}", "runs", "answered", "local model",
            "frame ms", "robot ms", "head ran"]  # fmt: skip
    rows: list[list[str]] = [head]
    for link in LINKS:
        for arm in ARMS:
            s = summ.get(link, {}).get(arm)
            if s is None:
                continue
            runs = ", ".join(_num(v, "{:.1f}") for v in s["overAlphaRuns"])
            rows.append([
                link, arm, _num(s["overAlpha"], "{:.1f}"), f"[{runs}]", _num(s["frames"], "{:g}"),
                _num(s["localShare"] * 100 if s["localShare"] == s["localShare"] else None,
                     "{:.0f} %"),
                _num(s["frameMillis"]), _num(s["robotMillis"]), ", ".join(s["actions"]),
            ])  # fmt: skip
    widths = [max(len(r[c]) for r in rows) for c in range(len(head))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip()
             for r in rows]  # fmt: skip
    return "\n".join([*lines, "", *_verdict_lines(result)])


def _verdict_lines(result: Mapping[str, Any]) -> Sequence[str]:
    v = result["verdict"]
    link = v["link"]
    arms = result["summary"].get(link, {})
    out = []
    if v.get("best") is None:
        out.append(f"{link}: no whole-module placement within maxRobotMillis {GAMMA_MS:g} ms "
                   "was measured: no verdict")  # fmt: skip
    else:
        best = arms[v["best"]]
        red = v["reduction"]
        said = "-" if red is None else f"{red:.1%} fewer"
        split = arms["split"]
        out.append(
            f"{link}: best whole-module placement within maxRobotMillis {GAMMA_MS:g} ms: "
            f"{v['best']}, {best['overAlpha']:.1f} frames over alpha; split "
            f"{split['overAlpha']:.1f} ({_num(split['localShare'] * 100, '{:.0f}')} % of its "
            f"frames by the local model): {said} (target: at least "
            f"{TARGET_REDUCTION:.0%}): {'met' if v['met'] else 'NOT met'}"
        )
    robot = arms.get(WHOLE_ROBOT)
    if robot is not None:
        over = robot["robotMillis"] > GAMMA_MS
        out.append(
            f"{link}: {WHOLE_ROBOT}: {robot['overAlpha']:.1f} frames over alpha, "
            f"{_num(robot['robotMillis'])} ms of robot compute a frame"
            + (f" (over maxRobotMillis {GAMMA_MS:g})" if over else "")
        )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.split.report", description=__doc__)
    ap.add_argument("--json", type=Path, default=Path("bench-split.json"))
    ap.add_argument("--docs", type=Path, default=None, help="write the docs page here too")
    ns = ap.parse_args(argv)
    record = read_record(ns.json)
    print(table(record["result"]))
    if ns.docs is not None:
        ours = f"`make bench-split` (e2e.bench.split.report) from {ns.json.name}"
        text = page("Split networks against whole-module placement", [record],
                    {SUITE: table}, {SUITE: ABOUT}, generated_by=ours)  # fmt: skip
        ns.docs.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
