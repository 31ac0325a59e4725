"""Fit the simulator's execution model on a pilot's runs, and on nothing else (issue 49).

    python -m e2e.bench.real.fit --pilot docs/benchmarks/real-nodes-pilot.json \\
        --out docs/benchmarks/real-nodes-model.json

The pilot is a short ``make bench-real`` (its own ``--arms``) recorded for this purpose; the
held-out runs the page judges the model on are never read here. Two steps, both by code:

1. **The cycle's cost** (``sim.model``): the profile corrections the closed loop adopted in
   the pilot's runs (``corrected``: a factor and the cycle's noise per (module, hardware
   type), as ``controllers.measure.observed.describe`` writes them), pooled over runs: the
   factor is the cycle-weighted mean, the noise the cycle-weighted root mean square.
2. **The kernel's spreading** (``sim.engine``): with those corrections, the ``spread`` on
   ``GRID`` whose replay of the pilot's completed runs (``replay``) is closest to what they
   measured: the least sum, over runs and modules, of |simulated - measured| in points.
   The smaller spread wins a tie, so a pilot that does not tell them apart keeps processor
   sharing.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.bench.real.plot import completed
from e2e.bench.real.replay import replay
from fogfleet.domain.rows import Learnt
from fogfleet.sim import ExecutionModel

__all__ = ["GRID", "fit", "parse_correction", "pooled_corrections", "replay_loss"]

GRID = tuple(k / 10 for k in range(11))  # the spreads tried
Run = Mapping[str, Any]
Key = tuple[str, str]

_SAID = re.compile(
    r"^(?P<module>\S+) on (?P<hw>\S+) x(?P<factor>[0-9.]+)"
    r"(?: \+ (?P<noise>[0-9.]+) ms noise)? \((?P<cycles>[0-9]+) cycles\)$"
)


def parse_correction(text: str) -> tuple[Key, Learnt]:
    """ "nav-controller on pi4 x1.07 + 8.1 ms noise (1186 cycles)" -> ((module, type),
    Learnt(1.07, 0.0081, 1186)); ValueError for anything else."""
    m = _SAID.match(text.strip())
    if m is None:
        raise ValueError(f"not a correction as the operator describes one: {text!r}")
    noise = float(m["noise"]) / 1e3 if m["noise"] else 0.0
    return (m["module"], m["hw"]), Learnt(float(m["factor"]), noise, float(m["cycles"]))


def pooled_corrections(runs: Iterable[Run]) -> dict[Key, Learnt]:
    """Every correction the runs adopted, pooled per (module, hardware type) over runs
    (module docstring, step 1)."""
    seen: dict[Key, list[Learnt]] = {}
    for run in filter(completed, runs):
        for text in run.get("corrected") or []:
            key, got = parse_correction(text)
            seen.setdefault(key, []).append(got)
    out: dict[Key, Learnt] = {}
    for key, each in sorted(seen.items()):
        n = sum(g.noise_cycles for g in each)
        w = [g.noise_cycles / n if n > 0 else 1 / len(each) for g in each]
        factor = sum(wk * g.factor for wk, g in zip(w, each, strict=True))
        noise = math.sqrt(sum(wk * g.noise**2 for wk, g in zip(w, each, strict=True)))
        out[key] = Learnt(factor, noise, n)
    return out


def replay_loss(runs: Sequence[Run], model: ExecutionModel) -> float:
    """Sum over the completed runs and their modules of |simulated - measured|, in points."""
    loss = 0.0
    for run in filter(completed, runs):
        simulated = replay(run, model)
        for module, got in run["measured"]["modules"].items():
            rate = got["missRate"]
            if rate is not None and module in simulated and not math.isnan(simulated[module]):
                loss += 100.0 * abs(simulated[module] - rate)
    return loss


def fit(pilot: Mapping[str, Any], source: str) -> tuple[ExecutionModel, list[dict[str, float]]]:
    """The model fitted on ``pilot``'s runs (module docstring) and each spread's loss."""
    runs = list(pilot.get("runs") or [])
    if not any(completed(r) for r in runs):
        raise ValueError("the pilot has no completed run")
    corrections = pooled_corrections(runs)
    losses = [
        {"spread": s, "loss": round(replay_loss(runs, ExecutionModel(corrections, s)), 3)}
        for s in GRID
    ]
    best = min(losses, key=lambda row: (row["loss"], row["spread"]))
    return ExecutionModel(corrections, best["spread"], source), losses


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.real.fit", description=__doc__)
    ap.add_argument("--pilot", type=Path, required=True, help="the pilot's bench-real.json")
    ap.add_argument("--out", type=Path, required=True, help="where the model's JSON goes")
    ns = ap.parse_args(argv)
    try:
        pilot = json.loads(ns.pilot.read_text(encoding="utf-8"))
        source = (
            f"pilot {ns.pilot.name}: {pilot.get('date')}, {pilot.get('machine')}, "
            f"{len(list(filter(completed, pilot.get('runs') or [])))} completed runs"
        )
        model, losses = fit(pilot, source)
    except (OSError, ValueError, KeyError) as exc:
        ap.error(f"--pilot {ns.pilot}: {exc}")
    command = "python -m e2e.bench.real.fit " + shlex.join(sys.argv[1:] if argv is None else argv)
    doc = model.as_json() | {"command": command, "losses": losses}
    ns.out.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    for row in losses:
        mark = "  <- fitted" if row["spread"] == model.spread else ""
        print(f"spread {row['spread']:.1f}: |simulated - measured| {row['loss']:8.2f} points{mark}")
    for (module, hw), got in sorted(model.corrections.items()):
        print(f"{module} on {hw}: x{got.factor:.3f} + {got.noise * 1e3:.1f} ms noise")
    print(f"wrote {ns.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
