"""The profiling contract (issue 10): N cycles of the module's work, one JSON line."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fogfleet.workload.__main__ import main
from fogfleet.workload.profile import MAX_MESSAGE_BYTES, profile_cycles, run_profile, summarise
from fogfleet.workload.spec import WorkloadSpec
from fogfleet.workload.work import CpuWork, RowWork, work_for

KEYS = {
    "module",
    "hardwareType",
    "node",
    "cpu",
    "cycles",
    "meanMillis",
    "stdMillis",
    "p95Millis",
    "maxMillis",
    "cpuSeconds",
    "wallSeconds",
}


def _spec(cycle_ms: float = 20, rows: bool = False, **env: str) -> WorkloadSpec:
    profile = [{"cpu": "100m", "meanMillis": 4, "stdMillis": 0}] if rows else []
    return WorkloadSpec.from_env(
        {
            "FOGFLEET_MODULE_SPEC": json.dumps({"cycleTimeMillis": cycle_ms, "profile": profile}),
            "FOGFLEET_MODULE": "mapper",
            "FOGFLEET_NODE": "bed-robot-1",
            "FOGFLEET_HARDWARE_TYPE": "bed-robot",
            "FOGFLEET_CPU": "100m",
            **env,
        }
    )


def test_summary_of_hand_computed_cycles() -> None:
    times = [0.010, 0.012, 0.014, 0.016, 0.100]  # ms: 10 12 14 16 100
    out = summarise(times, 0.0567, 1.23456, _spec())
    assert set(out) == KEYS
    assert out["cycles"] == 5 and out["meanMillis"] == pytest.approx(30.4)
    # sample std of 10, 12, 14, 16, 100
    assert out["stdMillis"] == pytest.approx(38.972, abs=1e-3)  # sqrt(6075.2 / 4)
    assert out["p95Millis"] == 100.0 and out["maxMillis"] == 100.0  # nearest rank: the 5th
    assert out["cpu"] == "100m" and out["hardwareType"] == "bed-robot"
    assert out["cpuSeconds"] == 0.057 and out["wallSeconds"] == 1.235
    assert summarise([0.005], 0, 0, _spec())["stdMillis"] == 0.0
    assert len(json.dumps(out).encode()) < MAX_MESSAGE_BYTES
    with pytest.raises(ValueError):
        summarise([], 0, 0, _spec())


def test_a_profiling_run_does_its_work_at_the_modules_pace(tmp_path: Path) -> None:
    out = tmp_path / "termination-log"
    t0 = time.monotonic()
    result = run_profile(_spec(cycle_ms=20), CpuWork(0.005), 5, str(out))
    took = time.monotonic() - t0
    lines = out.read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0]) == result
    assert result["cycles"] == 5
    assert 5.0 <= result["meanMillis"] < 500  # the work is CPU time: wall time is at least that
    assert result["cpuSeconds"] >= 5 * 0.005 * 0.95
    assert took >= 4 * 0.020  # paced: a cycle starts a cycle time after the previous one


def test_cpu_work_uses_the_cpu_asked_and_needs_no_row() -> None:
    spec = _spec()  # no rows
    with pytest.raises(ValueError):
        RowWork(spec, random.Random(1))
    work = work_for(
        WorkloadSpec(**{**spec.__dict__, "cpu_work_s": 0.02, "work_factor": 1.5}),
        random.Random(1),
    )
    assert isinstance(work, CpuWork)
    t0 = time.thread_time()
    wall = work.run()
    assert time.thread_time() - t0 >= 0.03 * 0.99 and wall >= 0.03 * 0.99


def test_profile_cycles_is_a_whole_positive_number() -> None:
    assert profile_cycles({}) is None and profile_cycles({"FOGFLEET_PROFILE_CYCLES": ""}) is None
    assert profile_cycles({"FOGFLEET_PROFILE_CYCLES": "20"}) == 20
    for bad in ("0", "-3", "many", "2.5"):
        with pytest.raises(ValueError, match="FOGFLEET_PROFILE_CYCLES"):
            profile_cycles({"FOGFLEET_PROFILE_CYCLES": bad})


def _run(tmp_path: Path, args: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    """``python -m fogfleet.workload`` with an rclpy that cannot be imported."""
    fake = tmp_path / "fake" / "rclpy"
    fake.mkdir(parents=True, exist_ok=True)
    (fake / "__init__.py").write_text("raise ImportError('a profiling run needs no ROS')\n")
    base = {k: v for k, v in os.environ.items() if not k.startswith("FOGFLEET_")}
    path = os.pathsep.join([str(fake.parent), base.get("PYTHONPATH", "")])
    full = {**base, "PYTHONPATH": path, "FOGFLEET_MODULE": "mapper", **env}
    return subprocess.run(
        [sys.executable, "-m", "fogfleet.workload", *args],
        env=full,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.integration
def test_the_program_profiles_without_ros_and_writes_its_termination_message(
    tmp_path: Path,
) -> None:
    out = tmp_path / "termination-log"
    proc = _run(
        tmp_path,
        ["module", "--cpu-work", "2"],
        FOGFLEET_MODULE_SPEC=json.dumps({"cycleTimeMillis": 20, "profile": []}),
        FOGFLEET_PROFILE_CYCLES="3",
        FOGFLEET_PROFILE_OUTPUT=str(out),
        FOGFLEET_CPU="250m",
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result["cycles"] == 3 and result["cpu"] == "250m" and result["meanMillis"] >= 2.0
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == result


@pytest.mark.integration
def test_nothing_to_profile_or_a_bad_count_exits_2_saying_why(tmp_path: Path) -> None:
    spec = json.dumps({"cycleTimeMillis": 20, "profile": []})
    nothing = _run(tmp_path, ["module"], FOGFLEET_MODULE_SPEC=spec, FOGFLEET_PROFILE_CYCLES="3")
    assert nothing.returncode == 2
    assert "--cpu-work" in nothing.stderr and "profile" in nothing.stderr
    bad = _run(
        tmp_path,
        ["module", "--cpu-work", "1"],
        FOGFLEET_MODULE_SPEC=spec,
        FOGFLEET_PROFILE_CYCLES="x",
    )
    assert bad.returncode == 2 and "FOGFLEET_PROFILE_CYCLES" in bad.stderr
    unwritable = _run(
        tmp_path,
        ["module", "--cpu-work", "1"],
        FOGFLEET_MODULE_SPEC=spec,
        FOGFLEET_PROFILE_CYCLES="1",
        FOGFLEET_PROFILE_OUTPUT=str(tmp_path / "no" / "such"),
    )
    assert unwritable.returncode == 1 and "cannot write the profile" in unwritable.stderr


@pytest.mark.parametrize("bad", ["0", "-1", "10001", "lots"])
def test_cpu_work_out_of_range_is_refused(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["module", "--cpu-work", bad])
    assert "milliseconds of CPU per cycle" in capsys.readouterr().err


def test_only_a_split_module_runs_whole(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("FOGFLEET_MODULE_SPEC", json.dumps({"cycleTimeMillis": 20, "profile": []}))
    monkeypatch.setenv("FOGFLEET_MODULE", "mapper")
    assert main(["module", "--whole", "edge"]) == 2
    assert "--whole: only a split module (spec.dnn)" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["module", "--whole", "cloud"])
    assert "--whole: invalid Whole value: 'cloud'" in capsys.readouterr().err
