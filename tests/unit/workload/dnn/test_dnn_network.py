"""The seeded network: deterministic, loadable by onnxruntime (the IR pin), cut where said."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from smallnet import SMALL

from fogfleet.workload.dnn.network import (
    IR_VERSION,
    OUTPUT,
    NetSpec,
    build_network,
    local_variant,
    parameter_count,
    split_point_names,
)
from fogfleet.workload.dnn.runner import Stage


def test_the_same_seed_builds_the_same_bytes(small_model: onnx.ModelProto) -> None:
    assert build_network(SMALL).SerializeToString() == small_model.SerializeToString()


def test_another_seed_draws_other_weights(small_model: onnx.ModelProto, frame: np.ndarray) -> None:
    other = build_network(NetSpec(input_size=32, width=0.25, classes=10, seed=SMALL.seed + 1))
    assert other.SerializeToString() != small_model.SerializeToString()
    assert not np.array_equal(Stage.of(other)(frame), Stage.of(small_model)(frame))


def test_onnxruntime_loads_the_model_and_answers_logits(
    small_model: onnx.ModelProto, frame: np.ndarray
) -> None:
    logits = Stage.of(small_model)(frame)
    assert small_model.ir_version == IR_VERSION == 10
    assert logits.shape == (1, SMALL.classes) and logits.dtype == np.float32
    assert np.all(np.isfinite(logits)) and np.ptp(logits) > 0


def test_onnx_s_own_ir_version_is_refused_which_is_why_it_is_pinned(
    small_model: onnx.ModelProto,
) -> None:
    # if this starts to pass, onnxruntime caught up with onnx and the pin may go
    unpinned = onnx.ModelProto()
    unpinned.CopyFrom(small_model)
    unpinned.ir_version = onnx.IR_VERSION
    assert onnx.IR_VERSION > IR_VERSION
    with pytest.raises(Exception, match="IR version"):
        ort.InferenceSession(unpinned.SerializeToString(), providers=["CPUExecutionProvider"])


def test_split_points_run_from_input_to_output_with_the_bottleneck_after_block_6() -> None:
    names = split_point_names(SMALL)
    assert names == ("b0", "b1", "b2", "b3", "b4", "b5", "b6", "bneck", "b7", "b8", "b9")
    assert "bneck" not in split_point_names(NetSpec(bottleneck=0))


def test_split_points_are_made_in_order_from_input_to_output(
    small_model: onnx.ModelProto,
) -> None:
    made = [out for node in small_model.graph.node for out in node.output]
    positions = [made.index(name) for name in split_point_names(SMALL)]
    assert positions == sorted(positions)
    assert made[-1] == OUTPUT


def test_the_local_variant_is_the_same_net_a_quarter_as_wide(
    small_model: onnx.ModelProto,
) -> None:
    spec = local_variant(SMALL)
    local = build_network(spec)
    assert spec.width == SMALL.width / 4 and spec.name != SMALL.name
    assert local.graph.input == small_model.graph.input
    assert local.graph.output == small_model.graph.output
    assert parameter_count(local) < parameter_count(small_model) / 4


def test_bottleneck_channels_are_the_narrow_tensor_s(small_model: onnx.ModelProto) -> None:
    convs = {n.output[0]: n for n in small_model.graph.node if n.op_type == "Conv"}
    weights = {t.name: tuple(t.dims) for t in small_model.graph.initializer}
    squeeze = weights[convs["bneck.conv"].input[1]]
    assert squeeze[:2] == (SMALL.bottleneck, SMALL.channels(512))


@pytest.mark.parametrize("size", [0, 16, 48, 100])
def test_a_frame_side_that_is_not_a_multiple_of_32_is_refused(size: int) -> None:
    with pytest.raises(ValueError, match="multiple of 32"):
        NetSpec(input_size=size)
