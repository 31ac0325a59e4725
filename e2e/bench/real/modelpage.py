"""The simulator against the measurements under two execution models (issue 49, item 3).

For every module of every judged arm (``summary.AGREEMENT_ARMS``): the median measured rate
over the arm's completed runs, the median the declared model gave them (as each run recorded
it) and the median a fitted model gives them (``replay``), each with issue 12's verdict
(``summary.simulator_agrees``: within max(25 % relative, 0.5 points)). The fitted model comes
from a pilot (``fit``); the runs judged here are held out from it. Pure, but for the replays.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from e2e.bench.real.plot import completed
from e2e.bench.real.replay import cpu_known, replay
from e2e.bench.real.summary import AGREEMENT_ARMS, median, simulator_agrees
from e2e.bench.real.tables import md_table, pct
from fogfleet.sim import ExecutionModel

__all__ = ["KINDS", "Cell", "cells", "inexact", "misses", "model_lines"]

Doc = Mapping[str, Any]
KINDS = ("measured", "declared", "fitted")
Cell = dict[str, float | None]  # kind -> median


def cells(doc: Doc, model: ExecutionModel) -> dict[str, dict[str, Cell]]:
    """module -> arm -> {measured, declared, fitted} medians over the arm's completed runs."""
    got: dict[str, dict[str, dict[str, list[float]]]] = {}
    for run in filter(completed, doc.get("runs") or []):
        arm = str(run["scheduler"])
        if arm not in AGREEMENT_ARMS:
            continue
        fitted = replay(run, model)
        for module, m in run["measured"]["modules"].items():
            declared = run["simulated"]["modules"].get(module, {}).get("missRate")
            row = got.setdefault(module, {}).setdefault(arm, {k: [] for k in KINDS})
            values = (m["missRate"], declared, fitted.get(module))
            for kind, value in zip(KINDS, values, strict=True):
                if value is not None and value == value:  # not None, not NaN
                    row[kind].append(float(value))
    return {
        module: {
            arm: {k: median(v) for k, v in arms[arm].items()}
            for arm in AGREEMENT_ARMS
            if arm in arms
        }
        for module, arms in sorted(got.items())
    }


def inexact(doc: Doc) -> list[str]:
    """The judged arms with a run whose replay lacks the CPU it ran with (``cpu_known``)."""
    runs = [r for r in filter(completed, doc.get("runs") or []) if not cpu_known(r)]
    return [a for a in AGREEMENT_ARMS if any(r["scheduler"] == a for r in runs)]


def misses(table: Mapping[str, Mapping[str, Cell]], kind: str) -> list[tuple[str, str]]:
    """The (arm, module) cells where ``kind``'s median misses the measured one."""
    return [
        (arm, module)
        for module, arms in table.items()
        for arm, cell in arms.items()
        if not simulator_agrees(cell["measured"], cell[kind])
    ]


def _verdict(cell: Cell, kind: str) -> str:
    return pct(cell[kind]) + ("" if simulator_agrees(cell["measured"], cell[kind]) else " ✗")


def model_lines(doc: Doc, model: ExecutionModel, model_file: str) -> list[str]:
    """The page's section: the fitted model, then per module and arm the three medians (✗: the
    simulator misses the measured median by more than max(25 % relative, 0.5 points))."""
    table = cells(doc, model)
    header = ["module", "arm", *KINDS]
    guessed = inexact(doc)
    rows = [
        [
            module,
            arm + (" †" if arm in guessed else ""),
            pct(cell["measured"]),
            _verdict(cell, "declared"),
            _verdict(cell, "fitted"),
        ]
        for module, by_arm in table.items()
        for arm, cell in by_arm.items()
    ]
    judged = len(rows)
    corrections = [
        f"  - {module} on {hw}: x{got.factor:.3f} + {got.noise * 1e3:.1f} ms noise "
        f"({got.noise_cycles:.0f} cycles)"
        for (module, hw), got in sorted(model.corrections.items())
    ]
    missed = {kind: misses(table, kind) for kind in ("declared", "fitted")}
    return [
        "## The simulator: declared model vs fitted model (medians)",
        "",
        f"The fitted model (`{model_file}`, {model.source}) was fitted on a pilot only "
        "(`python -m e2e.bench.real.fit`); the runs on this page are held out from it. "
        "It adds to the declared model:",
        "",
        f"- spread {model.spread:.1f}: the share of a short node's CPU that goes to the job "
        "that began executing last (the kernel's spreading of a shortage, `fogfleet.sim.engine`);",
        "- the cycle's cost per (module, hardware type) the closed loop measured in the pilot:",
        *corrections,
        "",
        md_table(header, rows),
        "",
        *(
            [
                "† Some of this arm's runs re-planned from learnt rows, and their replays may "
                "not run the CPU each instance then had: runs before 2026-12-01 did not record "
                "it (`cpu`), and a CPU chosen from learnt rows may be no rung of the declared "
                "ladder (`e2e.bench.real.replay.cpu_known`).",
                "",
            ]
            if guessed
            else []
        ),
        *(
            f"- {kind}: {judged - len(m)} of {judged} cells "
            "within max(25 % relative, 0.5 points); missed: "
            + (", ".join(f"{arm} {module}" for arm, module in m) or "none")
            for kind, m in missed.items()
        ),
        "",
    ]
