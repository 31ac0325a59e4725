"""The measured profile: medians after warm-up, and YAML in the dnn field's shape."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import pytest
import yaml
from smallnet import SMALL

from fogfleet.api.v1alpha1.dnn import Dnn
from fogfleet.workload.dnn.__main__ import main
from fogfleet.workload.dnn.network import split_point_names
from fogfleet.workload.dnn.profile import DnnProfile, measure, median_ms, to_yaml
from fogfleet.workload.dnn.runner import Stage
from fogfleet.workload.dnn.split import Split

FIELD = {"inputBytes", "outputBytes", "fullMillis", "splitPoints", "localModel"}
POINT = {"name", "headMillis", "tailMillis", "tensorBytes"}


@pytest.fixture(scope="module")
def profile() -> DnnProfile:
    return measure(SMALL, runs=2, warmup=1)


def test_median_times_only_the_runs_after_the_warm_up() -> None:
    ticks: Iterator[float] = iter([0.0, 0.005, 1.0, 1.001, 2.0, 2.003])  # runs of 5, 1, 3 ms
    calls = []
    ms = median_ms(lambda: calls.append(1), runs=3, warmup=2, clock=lambda: next(ticks))
    assert ms == pytest.approx(3.0)
    assert len(calls) == 5


def test_median_needs_a_run() -> None:
    with pytest.raises(ValueError, match="runs 0"):
        median_ms(lambda: None, runs=0, warmup=0)


def test_the_yaml_is_the_dnn_field_with_every_split_point_in_order(
    profile: DnnProfile, small_splits: dict[str, Split]
) -> None:
    dnn = yaml.safe_load(to_yaml(profile, SMALL, runs=2, warmup=1, clock="cpu"))["dnn"]
    assert set(dnn) == FIELD
    assert [p["name"] for p in dnn["splitPoints"]] == list(split_point_names(SMALL))
    assert all(set(p) == POINT for p in dnn["splitPoints"])
    assert [p["tensorBytes"] for p in dnn["splitPoints"]] == [
        s.tensor_bytes for s in small_splits.values()
    ]
    assert set(dnn["localModel"]) == {"name", "robotMillis"}
    # with the accuracies a user declares, it is a valid SoftwareModule field
    declared = {**dnn, "accuracy": 0.9, "localModel": {**dnn["localModel"], "accuracy": 0.6}}
    field = Dnn.model_validate(declared)
    assert [p.name for p in field.split_points] == [p["name"] for p in dnn["splitPoints"]]


def test_the_input_is_the_frame_and_the_output_the_logits(
    profile: DnnProfile, small_model: onnx.ModelProto, frame: np.ndarray
) -> None:
    assert profile.input_bytes == frame.nbytes == SMALL.input_size**2 * 3
    assert profile.output_bytes == Stage.of(small_model)(frame).nbytes == SMALL.classes * 4


def test_every_measured_time_is_positive(profile: DnnProfile) -> None:
    times = [profile.full_ms, profile.local_ms]
    times += [t for s in profile.split_points for t in (s.head_ms, s.tail_ms)]
    assert all(t > 0 for t in times), times


def test_the_command_prints_the_profile(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--size", "32", "--width", "0.25", "--classes", "10", "--seed", "7"]
    assert main(["profile", *args, "--runs", "1", "--warmup", "0", "--clock", "wall"]) == 0
    printed: dict[str, Any] = yaml.safe_load(capsys.readouterr().out)
    assert [p["name"] for p in printed["dnn"]["splitPoints"]] == list(split_point_names(SMALL))


def test_the_command_refuses_a_frame_side_not_a_multiple_of_32(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["profile", "--size", "100"])
    assert exit_.value.code == 2
    assert "multiple of 32" in capsys.readouterr().err


def test_the_models_command_writes_every_half_loadable(tmp_path: Path) -> None:
    args = ["--size", "32", "--width", "0.25", "--classes", "10", "--seed", "7"]
    assert main(["models", "--out", str(tmp_path), *args]) == 0
    halves = [f"{n}.{half}.onnx" for n in split_point_names(SMALL) for half in ("head", "tail")]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [*halves, "full.onnx", "local.onnx", "weights.bin"]
    )
    onnx.checker.check_model(onnx.load(tmp_path / "bneck.tail.onnx"))
