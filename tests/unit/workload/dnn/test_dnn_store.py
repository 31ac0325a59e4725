"""The model files: every weight once, read back by onnxruntime alone, head then tail exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from smallnet import SMALL

from fogfleet.workload.dnn import __main__ as dnn_main
from fogfleet.workload.dnn.layout import WEIGHTS
from fogfleet.workload.dnn.profile import CLOCKS
from fogfleet.workload.dnn.sessions import RobotNets, TailNets
from fogfleet.workload.dnn.store import write_models


def test_weights_are_stored_once_and_each_part_refers_to_them(tmp_path: Path) -> None:
    names = write_models(SMALL, tmp_path)
    weights = (tmp_path / WEIGHTS).stat().st_size
    graphs = [p.stat().st_size for p in tmp_path.glob("*.onnx")]
    assert len(graphs) == 2 + 2 * len(names)
    assert max(graphs) < 20_000 < weights  # graphs only; the weights are in one file


def test_head_then_tail_from_the_files_is_the_whole_network(tmp_path: Path) -> None:
    names = write_models(SMALL, tmp_path)
    robot, tail = RobotNets(tmp_path, names), TailNets(tmp_path, names)
    frame = robot.capture(1)
    whole = np.frombuffer(tail.tail(0, robot.head(0, frame)), np.float32)
    for k in range(1, len(names) + 1):
        split = np.frombuffer(tail.tail(k, robot.head(k, frame)), np.float32)
        assert np.array_equal(split, whole), names[k - 1]
    assert len(robot.local(frame)) == whole.nbytes


def test_the_command_line_offers_the_profiles_clocks() -> None:
    assert set(dnn_main.CLOCKS) == set(CLOCKS)
