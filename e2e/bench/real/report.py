"""The real-nodes comparison's summary, tables, Markdown section and figure from bench-real.json
(pure, but for ``main``; no cluster).

    python -m e2e.bench.real.report [--json bench-real.json]
        [--docs docs/benchmarks/real-nodes.md] [--plot docs/benchmarks/real-nodes-perception.svg]
        [--model docs/benchmarks/real-nodes-model.json]

``summarise`` (``e2e.bench.real.summary``) turns the runs into the document's "summary";
``table`` prints it for a terminal, ``markdown`` writes it for docs/, ``plot_svg``
(``e2e.bench.real.plot``) draws every run. Everything shown is generated from the document.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.bench.real.modelpage import model_lines
from e2e.bench.real.plot import arm_order, completed, plot_svg, rate
from e2e.bench.real.protocol import PERCEPTION, PRIMARY, REQUESTS
from e2e.bench.real.summary import (
    CONTROL,
    ENDPOINTS,
    LEVEL,
    RESAMPLES,
    SEED,
    TARGETS,
    TREATED,
    simulator_agrees,
    summarise,
)
from e2e.bench.real.tables import md_table, pct, text_table
from fogfleet.sim import ExecutionModel

__all__ = ["main", "markdown", "plot_svg", "simulator_agrees", "summarise", "table"]

Run = Mapping[str, Any]
Doc = Mapping[str, Any]
Rows = list[list[str]]


# --------------------------------------------------------------------------------------------
# rows, shared by the terminal and the Markdown tables


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
            pct(rate(r, "perception")),
            pct(rate(r, "perception", "simulated")),
            pct(rate(r, "allModules")),
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
                pct(p.get("median")),
                pct(s["simulatedPerception"].get(arm)),
                pct(a.get("median")),
            ]
        )
    return rows


def _comparison_line(doc: Doc, control: str = CONTROL) -> str:
    p = _summary(doc)[_primary(doc)]
    if control != CONTROL:
        p = p.get("vsRequests") or {"reduction": None, "ci95": [None, None], "pValue": None}
    lo, hi = p["ci95"]
    pv = "-" if p["pValue"] is None else f"{p['pValue']:.4g}"
    return (
        f"{_primary(doc)}: reduction of median {TREATED} vs {control} {pct(p['reduction'])} "
        f"(95 % bootstrap CI {pct(lo)} to {pct(hi)}), one-sided Mann-Whitney p = {pv}"
    )


def _comparison_lines(doc: Doc) -> list[str]:
    """Against k8s-default, and against k8s-requests where the document has its runs."""
    arms = _summary(doc)[_primary(doc)]
    others = [REQUESTS] if REQUESTS in arms else []
    return [_comparison_line(doc, c) for c in (CONTROL, *others)]


def _target_rows(doc: Doc) -> Rows:
    t = _summary(doc)["targets"]
    rows = [["PASS" if t[k] else "MISS", label] for k, label in TARGETS.items() if k in t]
    for arm, ok in t["simulatorAgrees"].items():
        label = f"simulator agrees with measured, {arm} (max(25 % relative, 0.5 points))"
        rows.append(["PASS" if ok else "MISS", label])
    return rows


def _module_header_rows(doc: Doc) -> tuple[list[str], Rows]:
    modules = _summary(doc)["modules"]
    arms = [a for a in arm_order(doc.get("runs") or []) if any(a in m for m in modules.values())]
    header = ["module"] + [f"{a} {k}" for a in arms for k in ("measured", "simulated")]
    rows = [
        [name] + [pct(by_arm.get(a, {}).get(k)) for a in arms for k in ("measured", "simulated")]
        for name, by_arm in modules.items()
    ]
    return header, rows


# --------------------------------------------------------------------------------------------
# renderings


# a run recorded before e2e/ split into bed, tests and bench (issue 34) names the old module
_RENAMED = {"python -m e2e.realbench": "python -m e2e.bench.real"}


def _command(doc: Doc) -> str:
    """The run's command as it is typed today (the same arguments)."""
    command = str(doc.get("command", "?"))
    for old, new in _RENAMED.items():
        if command == old or command.startswith(old + " "):
            return new + command[len(old) :]
    return command


def _bed_line(doc: Doc) -> str:
    bed = doc.get("bed") or {}
    nodes = ", ".join(
        f"`{n.get('name')}` ({n.get('cpu')} CPU, {n.get('hardwareType')})"
        for n in bed.get("nodes") or []
    )
    return (
        f"{doc.get('date', '?')}, {doc.get('machine', '?')}, `{_command(doc)}`; "
        f"profile {bed.get('profile', '?')}, scale factor F = {bed.get('scale', '?')}; "
        f"bed nodes: {nodes or '-'}"
    )


def _stopped(doc: Doc) -> list[str]:
    """A run of the protocol stopped before its end says so (``complete`` false): how many of
    the scheduled runs ran; every figure is over those."""
    if doc.get("complete", True):
        return []
    runs = doc.get("runs") or []
    scheduled = sum((doc.get("protocol") or {}).get("arms", {}).values())
    blocks = (doc.get("protocol") or {}).get("blocks", "?")
    reached = 1 + max((int(r.get("block", 0)) for r in runs), default=-1)
    return [
        f"Stopped before its end: {len(runs)} of the {scheduled} scheduled runs ran (block "
        f"{reached} of {blocks}); the schedule and protocol are unchanged, the runs left were "
        "never started, and every figure here is over the runs that ran."
    ]


def _parts(doc: Doc) -> list[str]:
    """A resumed run names its parts: which runs ran when, with which command."""
    parts = doc.get("parts") or []
    if not parts:
        return []
    said = "; ".join(
        f"runs {p['runs'][0]}-{p['runs'][1]} on {p.get('date', '?')}, "
        f"{p.get('machine') or 'machine not recorded'} "
        f"(`{p.get('command', '?')}`, {p.get('totalSeconds', '?')} s)"
        for p in parts
    )
    machines = {p.get("machine") for p in parts}
    other = (
        f" The parts ran on {len(machines)} different machines: each block holds every "
        "six-run arm, so each arm has runs on each of them, but the figures mix them."
        if len(machines) > 1
        else ""
    )
    return [
        f"Ran in {len(parts)} parts: {said}. A resumed run keeps the protocol and the "
        "schedule; it runs the scheduled runs the stopped one never started, in their "
        f"places.{other}"
    ]


def table(doc: Doc) -> str:
    """Plain-text tables for a terminal: every run, per arm, the comparison and targets, and
    per module x arm measured vs simulated."""
    proto = doc.get("protocol") or {}
    module_header, module_rows = _module_header_rows(doc)
    return "\n".join(
        [
            f"Real nodes, {_bed_line(doc)}; {proto.get('warmupSeconds', '?')} s warm-up, "
            f"{proto.get('windowSeconds', '?')} s windows",
            *_stopped(doc),
            *_parts(doc),
            "",
            text_table(RUN_HEADER, _run_rows(doc)),
            "",
            text_table(ARM_HEADER, _arm_rows(doc)),
            "",
            *_comparison_lines(doc),
            *(f"{verdict}  {label}" for verdict, label in _target_rows(doc)),
            "",
            text_table(module_header, module_rows),
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
        *_requests_lines(proto.get("k8sRequests")),
    ]


def _requests_lines(given: Mapping[str, Any] | None) -> list[str]:
    """How the k8s-requests arm's requests were chosen and what they were (issue 49)."""
    if not given:
        return []
    sigmas = float(given.get("sigmas", 3))
    said = []
    for module, r in (given.get("requests") or {}).items():
        sign = "<=" if r.get("fits", True) else "> (none fits: the largest row)"
        said.append(
            f"{module} {r['cpu']} ({r['meanMillis']:g} + {sigmas:g} x {r['stdMillis']:g} ms "
            f"{sign} {r['cycleMillis']:g} ms)"
        )
    return [
        f"- k8s-requests: the k8s-default Deployments with kube-scheduler's default scoring, "
        f"each module requesting the smallest CPU among its profile rows on the reference "
        f"hardware (`hardwareType: {given.get('referenceHardware', 'default')}`, the i9 rows "
        f"of `{given.get('source', 'e2e/bench/real/paper/modules.yaml')}`) whose mean + "
        f"{sigmas:g} std fits its cycle time, the largest row where none does; computed from "
        "those rows by `e2e.bench.real.scenario.honest_requests`, from nothing the bed "
        "measures, so fixed before the arm's first run: " + "; ".join(said),
        "- Pending: in kube-scheduler's arms an instance whose pod kube-scheduler cannot bind "
        "misses every cycle it was due in the window, measured and simulated alike; its "
        "placement reads `Pending`",
    ]


LOAD_HEADER = ["arm", "machine busy (cores)", "control plane (cores)"]
CONTROL_PLANE = ("etcd", "kube-apiserver", "kube-controller-manager", "kube-scheduler", "kwok")


def _load_rows(doc: Doc) -> Rows:
    """Per arm, the medians over its runs' windows of the cores the whole machine and the
    control plane kept busy (``cpuSeconds`` / window): the bed's headroom."""
    rows = []
    runs = doc.get("runs") or []
    for arm in arm_order(runs):
        busy, plane = [], []
        for r in runs:
            cpu, window = r.get("cpuSeconds") or {}, float(r.get("windowSeconds") or 0)
            if r["scheduler"] != arm or "machine" not in cpu or window <= 0:
                continue
            busy.append(cpu["machine"] / window)
            plane.append(sum(cpu.get(c, 0.0) for c in CONTROL_PLANE) / window)
        if busy:
            rows.append([arm, f"{statistics.median(busy):.2f}", f"{statistics.median(plane):.2f}"])
    return rows


def markdown(doc: Doc, *, plot_name: str, model: Sequence[str] = ()) -> str:
    """The docs/benchmarks section of the run in ``doc``, every figure generated from it
    (``model``: the section that judges a fitted execution model on it, ``modelpage``)."""
    module_header, module_rows = _module_header_rows(doc)
    targets = [f"- {verdict}: {label}" for verdict, label in _target_rows(doc)]
    return "\n".join(
        [
            "# Real nodes: the paper's experiment (`make bench-real`)",
            "",
            "The paper's real-robot experiment (multi-robot-edge-cloud-scheduling IV-C) on real",
            "kubelets and containerd: the fleet of `e2e/bench/real/paper/` on the paper bed",
            "(`make cluster-up PROFILE=paper`). `make bench-real` runs it (about 80 minutes) and",
            "writes `bench-real.json`; `make bench-real-report` generates this page and its figure",
            "from that file. Rates are fractions of cycles missed, shown in percent.",
            "",
            _bed_line(doc),
            "",
            *(f"**{line}**\n" for line in _stopped(doc)),
            *(f"{line}\n" for line in _parts(doc)),
            "Protocol:",
            "",
            *_protocol(doc),
            "",
            "## Per arm",
            "",
            md_table(ARM_HEADER, _arm_rows(doc)),
            "",
            *(f"**{line}**\n" for line in _comparison_lines(doc)),
            "## Targets",
            "",
            *targets,
            "",
            f"![{_primary(doc)} miss rate per run and arm]({plot_name})",
            "",
            "## Runs",
            "",
            md_table(RUN_HEADER, _run_rows(doc)),
            "",
            "## Modules: measured vs simulated (medians)",
            "",
            md_table(module_header, module_rows),
            "",
            *model,
            "## The bed's load over the windows (medians)",
            "",
            md_table(LOAD_HEADER, _load_rows(doc)),
            "",
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.real.report", description=__doc__)
    ap.add_argument("--json", type=Path, default=Path("bench-real.json"), help="the results")
    ap.add_argument("--docs", type=Path, help="write the Markdown section here")
    ap.add_argument(
        "--plot", type=Path, help="write the SVG here (default with --docs: <docs>-perception.svg)"
    )
    ap.add_argument(
        "--model",
        type=Path,
        help="a fitted execution model (`python -m e2e.bench.real.fit`): the page judges it "
        "beside the declared model",
    )
    ns = ap.parse_args(argv)
    if not ns.json.is_file():
        ap.error(f"{ns.json}: no such file (`make bench-real` writes it)")
    doc = json.loads(ns.json.read_text())
    print(table(doc))
    model: list[str] = []
    if ns.model is not None:
        try:
            fitted = ExecutionModel.from_json(json.loads(ns.model.read_text(encoding="utf-8")))
        except (OSError, ValueError) as exc:
            ap.error(f"--model {ns.model}: {exc}")
        model = model_lines(doc, fitted, ns.model.name)
        print("\n" + "\n".join(model))
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
        ns.docs.write_text(markdown(doc, plot_name=name, model=model))
        print(f"wrote {ns.docs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
