"""A split module's profiling Job: every part of the image's models timed, one result line."""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest
from smallnet import SMALL

from fogfleet.contract.dnn import PROFILE_KEY, RESULT_KEY
from fogfleet.workload.__main__ import main
from fogfleet.workload.dnn.layout import head_file, tail_file
from fogfleet.workload.dnn.measure import measure_models, run_dnn_profile
from fogfleet.workload.dnn.split import Split, tensor_bytes
from fogfleet.workload.dnn.store import write_models
from fogfleet.workload.profile import MAX_MESSAGE_BYTES

TICK_S = 0.001  # the test clock's step: every timed call takes exactly one tick


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, tuple[str, ...]]:
    """The small network's model files, as the image's build stage writes them."""
    folder = tmp_path_factory.mktemp("models")
    return folder, write_models(SMALL, folder)


def test_the_payload_names_every_split_point_in_order_with_its_tensors_bytes(
    models: tuple[Path, tuple[str, ...]],
    small_model: onnx.ModelProto,
    small_splits: dict[str, Split],
    frame: np.ndarray,
) -> None:
    folder, names = models
    payload = measure_models(folder, names, frames=2, warmup=1)
    assert payload["inputBytes"] == frame.nbytes == 32 * 32 * 3
    assert payload["outputBytes"] == tensor_bytes(small_model.graph.output[0]) == 10 * 4
    points = payload["splitPoints"]
    assert [p["name"] for p in points] == list(names)
    assert [p["tensorBytes"] for p in points] == [small_splits[n].tensor_bytes for n in names]
    assert payload["fullMillis"] > 0 and payload["localMillis"] > 0
    assert all(p["headMillis"] > 0 and p["tailMillis"] > 0 for p in points)


def test_each_part_is_the_median_of_its_timed_frames_on_the_clock_given(
    models: tuple[Path, tuple[str, ...]],
) -> None:
    folder, names = models
    ticks = itertools.count(step=TICK_S)
    calls = 0

    def clock() -> float:
        nonlocal calls
        calls += 1
        return next(ticks)

    payload = measure_models(folder, names[:2], frames=3, warmup=0, clock=clock)
    parts = [payload["fullMillis"], payload["localMillis"]] + [
        p[k] for p in payload["splitPoints"] for k in ("headMillis", "tailMillis")
    ]
    assert parts == [TICK_S * 1e3] * 6
    assert calls == 6 * 3 * 2  # a start and an end per timed frame of every part


def test_a_missing_model_file_is_named(models: tuple[Path, tuple[str, ...]]) -> None:
    folder, names = models
    with pytest.raises(FileNotFoundError, match=r"no model nosuch\.head\.onnx"):
        measure_models(folder, [names[0], "nosuch"], frames=1)


def test_the_result_line_is_the_jobs_mean_and_the_payload(
    models: tuple[Path, tuple[str, ...]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, names = models
    out = tmp_path / "termination-log"
    result = run_dnn_profile(folder, names[-2:], 4, str(out))
    line = out.read_text()
    assert line.count("\n") == 1 and ", " not in line  # one compact line
    assert json.loads(line) == result == json.loads(capsys.readouterr().out.splitlines()[-1])
    assert result["cycles"] == 4 and result["meanMillis"] > 0 and result["stdMillis"] >= 0
    assert result["cpuSeconds"] > 0 and result["wallSeconds"] > 0
    assert [p["name"] for p in result[RESULT_KEY]["splitPoints"]] == list(names[-2:])


def test_a_line_too_long_for_a_termination_message_is_refused_and_not_written(
    models: tuple[Path, tuple[str, ...]], tmp_path: Path
) -> None:
    shared, names = models
    folder = shutil.copytree(shared, tmp_path / "models")
    many = [f"{'x' * 100}{k}" for k in range(MAX_MESSAGE_BYTES // 100)]
    for name in many:  # the same small halves under long names
        shutil.copy(folder / head_file(names[0]), folder / head_file(name))
        shutil.copy(folder / tail_file(names[0]), folder / tail_file(name))
    out = tmp_path / "termination-log"
    with pytest.raises(ValueError, match="too many split points"):
        run_dnn_profile(folder, many, 1, str(out))
    assert not out.exists()


def _profiling_job(
    monkeypatch: pytest.MonkeyPatch, folder: Path, splits: list[str], out: Path
) -> None:
    """The environment the operator's profiling Job gives a split module's pod."""
    spec = {"cycleTimeMillis": 100, PROFILE_KEY: {"splitPoints": splits}}
    monkeypatch.setenv("FOGFLEET_MODULE_SPEC", json.dumps(spec))
    monkeypatch.setenv("FOGFLEET_MODULE", "detector")
    monkeypatch.setenv("FOGFLEET_PROFILE_CYCLES", "5")
    monkeypatch.setenv("FOGFLEET_DNN_MODELS", str(folder))
    monkeypatch.setenv("FOGFLEET_PROFILE_OUTPUT", str(out))


def test_the_program_profiles_a_split_module_into_its_termination_message(
    models: tuple[Path, tuple[str, ...]],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder, names = models
    out = tmp_path / "termination-log"
    _profiling_job(monkeypatch, folder, list(names[:3]), out)
    assert main(["module"]) == 0
    (line,) = out.read_text().splitlines()
    result = json.loads(line)
    assert result["cycles"] == 5
    assert [p["name"] for p in result[RESULT_KEY]["splitPoints"]] == list(names[:3])
    assert "profiling detector's network" in capsys.readouterr().out


def test_the_program_says_which_model_is_missing_and_exits_1(
    models: tuple[Path, tuple[str, ...]],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder, _ = models
    out = tmp_path / "termination-log"
    _profiling_job(monkeypatch, folder, ["nosuch"], out)
    assert main(["module"]) == 1
    assert "fogfleet-workload: no model nosuch.head.onnx" in capsys.readouterr().err
    assert not out.exists()
