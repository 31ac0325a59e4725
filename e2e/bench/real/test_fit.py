"""The execution model fitted on a pilot, the replay of recorded runs, and the page that judges
both models (pure; no cluster)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from e2e.bench.real.fit import fit, main, parse_correction, pooled_corrections
from e2e.bench.real.modelpage import cells, misses, model_lines
from e2e.bench.real.plot import completed
from e2e.bench.real.replay import cpu_known, replay, scenario_of
from fogfleet.domain.rows import Learnt
from fogfleet.sim import DECLARED, ExecutionModel

HELD_OUT = Path(__file__).resolve().parents[3] / "docs" / "benchmarks" / "real-nodes.json"
ROBOT_BOUND = ("nav-localization", "nav-controller")
ROBOTS = ("paper-robot-1", "paper-robot-2")


def _run(arm: str, seed: int, corrected: list[str] | None = None) -> dict[str, Any]:
    """A k8s-default-like run: the navigation's hard parts on their robots, every other
    instance on paper-edge-1 (short of CPU), measured as nothing yet."""
    placement = {
        f"{inst.robot}/{inst.module}": inst.robot if inst.module in ROBOT_BOUND else "paper-edge-1"
        for inst in scenario_of(arm).problem.instances
    }
    return {
        "scheduler": arm,
        "seed": seed,
        "position": seed,
        "windowSeconds": 60.0,
        "failed": None,
        "placement": placement,
        "corrected": corrected or [],
        "measured": {"modules": {}},
        "simulated": {"modules": {}},
    }


def _measured_as(run: dict[str, Any], model: ExecutionModel) -> dict[str, Any]:
    run["measured"]["modules"] = {m: {"missRate": r} for m, r in replay(run, model).items()}
    run["simulated"]["modules"] = {m: {"missRate": r} for m, r in replay(run, DECLARED).items()}
    return run


def test_a_correction_reads_as_the_operator_says_it() -> None:
    key, got = parse_correction("nav-controller on pi4 x1.07 + 8.1 ms noise (1186 cycles)")
    assert key == ("nav-controller", "pi4")
    assert (got.factor, got.noise, got.noise_cycles) == pytest.approx((1.07, 0.0081, 1186))
    key, got = parse_correction("scene-segmentation on i9-9900 x1.03 (158 cycles)")
    assert (key[1], got.factor, got.noise) == ("i9-9900", 1.03, 0.0)
    with pytest.raises(ValueError, match="not a correction"):
        parse_correction("nav-controller on pi4 faster")


def test_corrections_pool_over_runs_weighted_by_cycles() -> None:
    runs = [
        _run("nsga2", 1, ["nav-controller on pi4 x1.00 + 3.0 ms noise (100 cycles)"]),
        _run("nsga2", 2, ["nav-controller on pi4 x1.20 + 9.0 ms noise (300 cycles)"]),
        _run("nsga2", 3, ["nav-controller on pi4 x9.00 (900 cycles)"]) | {"failed": "timeout"},
    ]
    got = pooled_corrections(runs)[("nav-controller", "pi4")]
    assert got.factor == pytest.approx(1.15)  # the failed run counts nothing
    assert got.noise == pytest.approx(math.sqrt(0.25 * 3e-3**2 + 0.75 * 9e-3**2))
    assert got.noise_cycles == 400


def test_the_fit_finds_the_spread_that_made_the_pilot() -> None:
    truth = ExecutionModel({("nav-controller", "pi4"): Learnt(1.05, 0.004, 1000)}, 0.6)
    said = ["nav-controller on pi4 x1.05 + 4.0 ms noise (1000 cycles)"]
    pilot = {"runs": [_measured_as(_run("k8s-default", s, said), truth) for s in (1, 2)]}
    model, losses = fit(pilot, "synthetic")
    assert model.spread == 0.6
    assert model.corrections == {("nav-controller", "pi4"): Learnt(1.05, 0.004, 2000)}
    assert min(row["loss"] for row in losses) == 0.0
    assert losses[0]["loss"] > 0  # processor sharing alone would not have made it


def test_a_pilot_without_a_completed_run_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no completed run"):
        fit({"runs": [_run("nsga2", 1) | {"failed": "x"}]}, "empty")
    bad = tmp_path / "pilot.json"
    bad.write_text(json.dumps({"runs": []}))
    with pytest.raises(SystemExit):
        main(["--pilot", str(bad), "--out", str(tmp_path / "model.json")])


def test_the_declared_model_replays_the_recorded_runs() -> None:
    doc = json.loads(HELD_OUT.read_text())
    gaps = []
    for run in filter(completed, doc["runs"]):
        got = replay(run, DECLARED)
        recorded = run["simulated"]["modules"]
        gaps.append(max(abs(got[m] - recorded[m]["missRate"]) for m in recorded))
    assert len(gaps) == 24
    # one closed-loop run re-planned onto a CPU rung the placement alone does not record
    assert sum(g > 0 for g in gaps) <= 1
    assert max(gaps) < 0.005


def test_the_page_marks_each_cell_a_model_misses() -> None:
    truth = ExecutionModel(spread=1.0)
    doc = {"runs": [_measured_as(_run("k8s-default", s), truth) for s in (1, 2)]}
    table = cells(doc, truth)
    assert misses(table, "fitted") == []
    assert ("k8s-default", "human-pose-estimation") in misses(table, "declared")
    lines = "\n".join(model_lines(doc, truth, "model.json")).splitlines()
    assert any(line.startswith("- fitted: 6 of 6 cells") for line in lines)
    row = next(line for line in lines if line.startswith("| human-pose-estimation |"))
    assert row.count("✗") == 1  # the declared model's cell


def test_a_replay_says_whether_it_ran_the_cpu_the_run_recorded() -> None:
    # nsga2's first plan gives nav-controller 67m, the one rung of its declared ladder on a
    # robot; a closed loop that re-planned it onto 133m from learnt rows ran a CPU the
    # declared ladder cannot replay
    first = _run("nsga2", 1, ["nav-controller on pi4 x1.00 + 6.0 ms noise (1000 cycles)"])
    assert not cpu_known(first)  # re-planned, and nothing recorded
    same = first | {"cpu": {f"{r}/nav-controller": "67m" for r in ROBOTS}}
    assert cpu_known(same)
    other = first | {"cpu": {f"{r}/nav-controller": "133m" for r in ROBOTS}}
    assert not cpu_known(other)
    assert cpu_known(_run("nsga2", 1))  # never re-planned: the first plan's CPU
    assert cpu_known(_run("k8s-default", 1, ["anything"]))  # plain Deployments: nominal
