"""The real-nodes comparison's summary, tables, Markdown section and figure from bench-real.json
(pure, but for ``main``; no cluster).

    python -m e2e.realbench.report [--json bench-real.json]
        [--docs docs/benchmarks/real-nodes.md] [--plot docs/benchmarks/real-nodes-perception.svg]

``summarise`` turns the runs into the document's "summary": per arm the medians over the
completed runs (a failed run is listed, never counted), nsga2's reduction of k8s-default's
primary-endpoint median with its bootstrap CI and one-sided Mann-Whitney p, and the issue's
targets. ``table`` prints it for a terminal, ``markdown`` writes it for docs/, ``plot_svg``
(``e2e.realbench.plot``) draws every run. Everything shown is generated from the document.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.realbench.plot import arm_order, completed, plot_svg, rate
from e2e.realbench.protocol import K8S, NSGA2, ONBOARD, PERCEPTION, PRIMARY
from e2e.realbench.stats import bootstrap_reduction_ci, mann_whitney_less, reduction

__all__ = ["main", "markdown", "plot_svg", "simulator_agrees", "summarise", "table"]

Run = Mapping[str, Any]
Doc = Mapping[str, Any]
Rows = list[list[str]]

TREATED, CONTROL = NSGA2, K8S
RESAMPLES, LEVEL, SEED = 10000, 0.95, 0
ENDPOINTS = {
    "perception": "missed / cycles pooled over every instance of {perception}",
    "allModules": "the mean over modules of each module's missed / cycles",
}
TARGETS = {
    "reductionAtLeast90": f"reduction {TREATED} vs {CONTROL} >= 90 %",
    "pAtMost005": "one-sided Mann-Whitney p <= 0.05",
    "sixRunsEach": f">= 6 completed runs of {TREATED} and of {CONTROL}",
    "onboardWorst": f"{ONBOARD}'s median above {TREATED}'s and {CONTROL}'s",
}


def _safe(x: float | None) -> float | None:
    """JSON has no NaN: None stands for "no figure"."""
    return None if x is None or math.isnan(x) or math.isinf(x) else float(x)


def _median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def _values(runs: Sequence[Run], arm: str, endpoint: str, kind: str = "measured") -> list[float]:
    """The arm's completed runs' rates on the endpoint, in run order."""
    mine = (r for r in runs if r["scheduler"] == arm and completed(r))
    return [v for v in (rate(r, endpoint, kind) for r in mine) if v is not None]


def simulator_agrees(measured: float | None, simulated: float | None) -> bool:
    """Issue 12's agreement rule: within 25 % relative or 0.5 points, whichever is larger."""
    if measured is None or simulated is None:
        return False
    return abs(measured - simulated) <= max(0.25 * measured, 0.005)


def _endpoint(
    runs: Sequence[Run], arms: Sequence[str], endpoint: str, primary: bool
) -> dict[str, Any]:
    block: dict[str, Any] = {}
    for arm in arms:
        values = _values(runs, arm, endpoint)
        n = sum(1 for r in runs if r["scheduler"] == arm and completed(r))
        block[arm] = {"median": _safe(_median(values)), "runs": n}
        if primary:
            block[arm]["values"] = values
    return block


def _comparison(treated: Sequence[float], control: Sequence[float]) -> dict[str, Any]:
    if not treated or not control:
        return {"reduction": None, "ci95": [None, None], "pValue": None}
    lo, hi = bootstrap_reduction_ci(treated, control, resamples=RESAMPLES, level=LEVEL, seed=SEED)
    return {
        "reduction": _safe(reduction(statistics.median(treated), statistics.median(control))),
        "ci95": [_safe(lo), _safe(hi)],
        "pValue": mann_whitney_less(treated, control),
    }


def _modules(
    runs: Sequence[Run], arms: Sequence[str]
) -> dict[str, dict[str, dict[str, float | None]]]:
    names: set[str] = set()
    for r in filter(completed, runs):
        for kind in ("measured", "simulated"):
            names |= set(((r.get(kind) or {}).get("modules") or {}).keys())
    return {
        m: {
            arm: {k: _safe(_median(_values(runs, arm, m, k))) for k in ("measured", "simulated")}
            for arm in arms
        }
        for m in sorted(names)
    }


def _targets(
    summary: Mapping[str, Any], primary: str, perception: Mapping[str, Any]
) -> dict[str, Any]:
    p = summary[primary]

    def med(arm: str) -> float | None:
        return p[arm]["median"] if arm in p else None

    onboard, worse = med(ONBOARD), [med(TREATED), med(CONTROL)]
    sim = summary["simulatedPerception"]
    return {
        "reductionAtLeast90": p["reduction"] is not None and p["reduction"] >= 0.90,
        "pAtMost005": p["pValue"] is not None and p["pValue"] <= 0.05,
        "sixRunsEach": all(p.get(a, {}).get("runs", 0) >= 6 for a in (TREATED, CONTROL)),
        "onboardWorst": onboard is not None and all(m is not None and onboard > m for m in worse),
        "simulatorAgrees": {
            a: simulator_agrees(perception.get(a, {}).get("median"), sim.get(a))
            for a in (TREATED, CONTROL)
        },
    }


def summarise(runs: Sequence[Run], *, primary: str = PRIMARY) -> dict[str, Any]:
    """bench-real.json's "summary": medians over each arm's completed runs (an arm with none
    is left out), and on the ``primary`` endpoint the runs' values, nsga2's reduction of
    k8s-default's median with its 95 % bootstrap CI and one-sided Mann-Whitney p, and the
    targets. JSON-safe: None where a figure does not exist."""
    arms = [a for a in arm_order(runs) if any(r["scheduler"] == a and completed(r) for r in runs)]
    summary: dict[str, Any] = {
        ep: _endpoint(runs, arms, ep, ep == primary)
        for ep in dict.fromkeys(("perception", "allModules", primary))
    }
    summary[primary] |= _comparison(
        _values(runs, TREATED, primary), _values(runs, CONTROL, primary)
    )
    summary["modules"] = _modules(runs, arms)
    summary["simulatedPerception"] = {
        a: _safe(_median(_values(runs, a, "perception", "simulated"))) for a in arms
    }
    summary["targets"] = _targets(summary, primary, summary["perception"])
    return summary


# --------------------------------------------------------------------------------------------
# rows, shared by the terminal and the Markdown tables


def _pct(x: float | None) -> str:
    return "-" if x is None or math.isnan(x) else f"{100 * x:.2f} %"


def _summary(doc: Doc) -> Mapping[str, Any]:
    given: Mapping[str, Any] | None = doc.get("summary")
    if given:
        return given
    return summarise(doc.get("runs") or [], primary=_primary(doc))


def _primary(doc: Doc) -> str:
    return str(doc.get("primaryEndpoint", PRIMARY))


RUN_HEADER = [
    "arm",
    "seed",
    "position",
    "block",
    "perception measured",
    "perception simulated",
    "all modules",
    "perception ran on",
    "failed",
]


SHORT = {"human-pose-estimation": "pose", "scene-segmentation": "seg"}


def _perception_nodes(run: Run) -> str:
    """Where the run's perception instances ran ("pose e1 e1, seg e2 r1"): the placement that
    decides the primary endpoint, for every run (kube-scheduler's differ run by run)."""
    where = run.get("placement") or {}
    parts = []
    for module in PERCEPTION:
        nodes = [node for key, node in sorted(where.items()) if key.endswith("/" + module)]
        if nodes:
            short = " ".join(n.replace("paper-", "").replace("robot-", "r").replace("edge-", "e")
                             for n in nodes)  # fmt: skip
            parts.append(f"{SHORT.get(module, module)} {short}")
    return ", ".join(parts)


def _run_rows(doc: Doc) -> Rows:
    return [
        [
            str(r["scheduler"]),
            str(r.get("seed", "-")),
            str(r.get("position", "-")),
            str(r.get("block", "-")),
            _pct(rate(r, "perception")),
            _pct(rate(r, "perception", "simulated")),
            _pct(rate(r, "allModules")),
            _perception_nodes(r),
            str(r.get("failed") or ""),
        ]
        for r in doc.get("runs") or []
    ]


ARM_HEADER = [
    "arm",
    "runs",
    "failed",
    "perception measured",
    "perception simulated",
    "all modules",
]


def _arm_rows(doc: Doc) -> Rows:
    s, runs = _summary(doc), doc.get("runs") or []
    rows = []
    for arm in arm_order(runs):
        failed = sum(1 for r in runs if r["scheduler"] == arm and not completed(r))
        p, a = s["perception"].get(arm, {}), s["allModules"].get(arm, {})
        rows.append(
            [
                arm,
                str(p.get("runs", 0)),
                str(failed),
                _pct(p.get("median")),
                _pct(s["simulatedPerception"].get(arm)),
                _pct(a.get("median")),
            ]
        )
    return rows


def _comparison_line(doc: Doc) -> str:
    p = _summary(doc)[_primary(doc)]
    lo, hi = p["ci95"]
    pv = "-" if p["pValue"] is None else f"{p['pValue']:.4g}"
    return (
        f"{_primary(doc)}: reduction of median {TREATED} vs {CONTROL} {_pct(p['reduction'])} "
        f"(95 % bootstrap CI {_pct(lo)} to {_pct(hi)}), one-sided Mann-Whitney p = {pv}"
    )


def _target_rows(doc: Doc) -> Rows:
    t = _summary(doc)["targets"]
    rows = [["PASS" if t[k] else "MISS", label] for k, label in TARGETS.items()]
    for arm, ok in t["simulatorAgrees"].items():
        label = f"simulator agrees with measured, {arm} (max(25 % relative, 0.5 points))"
        rows.append(["PASS" if ok else "MISS", label])
    return rows


def _module_header_rows(doc: Doc) -> tuple[list[str], Rows]:
    modules = _summary(doc)["modules"]
    arms = [a for a in arm_order(doc.get("runs") or []) if any(a in m for m in modules.values())]
    header = ["module"] + [f"{a} {k}" for a in arms for k in ("measured", "simulated")]
    rows = [
        [name] + [_pct(by_arm.get(a, {}).get(k)) for a in arms for k in ("measured", "simulated")]
        for name, by_arm in modules.items()
    ]
    return header, rows


# --------------------------------------------------------------------------------------------
# renderings


def _text_table(header: list[str], rows: Rows) -> str:
    widths = [max(len(r[k]) for r in [header, *rows]) for k in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    head = "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip()
    return "\n".join([head, "-" * len(head), *lines])


def _md_table(header: list[str], rows: Rows) -> str:
    def line(cells: list[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(header), "|" + "---|" * len(header), *map(line, rows)])


def _bed_line(doc: Doc) -> str:
    bed = doc.get("bed") or {}
    nodes = ", ".join(
        f"`{n.get('name')}` ({n.get('cpu')} CPU, {n.get('hardwareType')})"
        for n in bed.get("nodes") or []
    )
    return (
        f"{doc.get('date', '?')}, {doc.get('machine', '?')}, `{doc.get('command', '?')}`; "
        f"profile {bed.get('profile', '?')}, scale factor F = {bed.get('scale', '?')}; "
        f"bed nodes: {nodes or '-'}"
    )


def table(doc: Doc) -> str:
    """Plain-text tables for a terminal: every run, per arm, the comparison and targets, and
    per module x arm measured vs simulated."""
    proto = doc.get("protocol") or {}
    module_header, module_rows = _module_header_rows(doc)
    return "\n".join(
        [
            f"Real nodes, {_bed_line(doc)}; {proto.get('warmupSeconds', '?')} s warm-up, "
            f"{proto.get('windowSeconds', '?')} s windows",
            "",
            _text_table(RUN_HEADER, _run_rows(doc)),
            "",
            _text_table(ARM_HEADER, _arm_rows(doc)),
            "",
            _comparison_line(doc),
            *(f"{verdict}  {label}" for verdict, label in _target_rows(doc)),
            "",
            _text_table(module_header, module_rows),
        ]
    )


def _protocol(doc: Doc) -> list[str]:
    proto, ep = doc.get("protocol") or {}, _primary(doc)
    arms = ", ".join(f"{a} x {n}" for a, n in (proto.get("arms") or {}).items())
    order = proto.get("order", "the arms' order alternates from block to block")
    perception = " and ".join(proto.get("perceptionModules") or PERCEPTION)
    return [
        f"- arms and runs: {arms or '-'}",
        f"- each run: {proto.get('warmupSeconds', '?')} s warm-up, then a "
        f"{proto.get('windowSeconds', '?')} s measured window",
        f"- order: {order} ({proto.get('blocks', '?')} blocks)",
        f"- primary endpoint: `{ep}` miss rate per run, "
        + ENDPOINTS.get(ep, ep).format(perception=perception),
        f"- statistics: medians over each arm's completed runs; reduction = 1 - median({TREATED})"
        f" / median({CONTROL}); {100 * LEVEL:g} % percentile bootstrap CI ({RESAMPLES} resamples, "
        f"each arm resampled on its own, seed {SEED}); exact one-sided Mann-Whitney U p "
        f"({TREATED} < {CONTROL}); failed runs are listed, not counted",
    ]


def markdown(doc: Doc, *, plot_name: str) -> str:
    """The docs/benchmarks section of the run in ``doc``, every figure generated from it."""
    module_header, module_rows = _module_header_rows(doc)
    targets = [f"- {verdict}: {label}" for verdict, label in _target_rows(doc)]
    return "\n".join(
        [
            "## Real nodes: the paper's experiment (`make bench-real`)",
            "",
            _bed_line(doc),
            "",
            "Protocol:",
            "",
            *_protocol(doc),
            "",
            "### Per arm",
            "",
            _md_table(ARM_HEADER, _arm_rows(doc)),
            "",
            f"**{_comparison_line(doc)}**",
            "",
            "### Targets",
            "",
            *targets,
            "",
            f"![{_primary(doc)} miss rate per run and arm]({plot_name})",
            "",
            "### Runs",
            "",
            _md_table(RUN_HEADER, _run_rows(doc)),
            "",
            "### Modules: measured vs simulated (medians)",
            "",
            _md_table(module_header, module_rows),
            "",
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.realbench.report", description=__doc__)
    ap.add_argument("--json", type=Path, default=Path("bench-real.json"), help="the results")
    ap.add_argument("--docs", type=Path, help="write the Markdown section here")
    ap.add_argument(
        "--plot", type=Path, help="write the SVG here (default with --docs: <docs>-perception.svg)"
    )
    ns = ap.parse_args(argv)
    if not ns.json.is_file():
        ap.error(f"{ns.json}: no such file (`make bench-real` writes it)")
    doc = json.loads(ns.json.read_text())
    print(table(doc))
    plot: Path | None = ns.plot
    if plot is None and ns.docs is not None:
        plot = ns.docs.with_name(f"{ns.docs.stem}-perception.svg")
    if plot is not None:
        plot.parent.mkdir(parents=True, exist_ok=True)
        plot.write_text(plot_svg(doc))
        print(f"wrote {plot}")
    if ns.docs is not None and plot is not None:
        name = Path(os.path.relpath(plot.resolve(), ns.docs.resolve().parent)).as_posix()
        ns.docs.parent.mkdir(parents=True, exist_ok=True)
        ns.docs.write_text(markdown(doc, plot_name=name))
        print(f"wrote {ns.docs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
