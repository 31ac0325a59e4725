"""Cutting the network: head then tail is the whole network, exactly, at every split point;
what crosses is prod(shape) x the element's size (DNNSPLIT.md 3.4, item 1)."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from smallnet import SMALL

from fogfleet.workload.dnn.network import IR_VERSION, split_point_names
from fogfleet.workload.dnn.runner import SplitRunner, Stage
from fogfleet.workload.dnn.split import Split, split_at, tensor_bytes

NAMES = split_point_names(SMALL)


@pytest.fixture(scope="module")
def whole(small_model: onnx.ModelProto, frame: np.ndarray) -> np.ndarray:
    return Stage.of(small_model)(frame)


@pytest.mark.parametrize("name", NAMES)
def test_head_then_tail_is_the_whole_network_exactly(
    name: str, small_splits: dict[str, Split], frame: np.ndarray, whole: np.ndarray
) -> None:
    two_parts = SplitRunner.of(small_splits[name])(frame)
    assert two_parts.shape == whole.shape
    assert float(np.max(np.abs(two_parts - whole))) == 0.0


@pytest.mark.parametrize("name", NAMES)
def test_what_crosses_is_the_shape_times_the_element_size(
    name: str, small_splits: dict[str, Split], frame: np.ndarray
) -> None:
    split = small_splits[name]
    crossing = Stage.of(split.head)(frame)
    assert crossing.shape == split.shape
    assert split.tensor_bytes == int(np.prod(crossing.shape)) * crossing.dtype.itemsize
    assert split.tensor_bytes == crossing.nbytes == tensor_bytes(split.tail.graph.input[0])


def test_the_bottleneck_crosses_far_fewer_bytes_than_the_block_before_it(
    small_splits: dict[str, Split],
) -> None:
    side = SMALL.input_size // 16  # b6's feature map: four halvings
    assert small_splits["bneck"].tensor_bytes == SMALL.bottleneck * side * side * 4
    assert small_splits["bneck"].tensor_bytes * 8 <= small_splits["b6"].tensor_bytes


def test_the_halves_share_out_the_whole_network_s_nodes_and_keep_the_ir_pin(
    small_model: onnx.ModelProto, small_splits: dict[str, Split]
) -> None:
    whole = [n.name for n in small_model.graph.node]
    for split in small_splits.values():
        head = [n.name for n in split.head.graph.node]
        tail = [n.name for n in split.tail.graph.node]
        assert head + tail == whole, split.name
        assert split.head.ir_version == split.tail.ir_version == IR_VERSION


def test_a_later_split_runs_more_on_the_robot(small_splits: dict[str, Split]) -> None:
    heads = [len(small_splits[name].head.graph.node) for name in NAMES]
    assert heads == sorted(heads) and len(set(heads)) == len(heads)


def test_cutting_at_a_tensor_the_network_lacks_is_refused(small_model: onnx.ModelProto) -> None:
    with pytest.raises(ValueError, match="no tensor 'b42'"):
        split_at(small_model, "b42")
