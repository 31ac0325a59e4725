"""The split DNN at full size (224x224 frames, width 1): over the unit tier's second.

The bytes that cross at each split point are those DNNSPLIT.md 3.3 measured (the bottleneck
cuts b6's 401 408 B to 6 272 B), head then tail is still the whole network exactly, and the
local variant runs in well under the whole network's time.
"""

from __future__ import annotations

import numpy as np
import onnx
import pytest

from fogfleet.workload.dnn.network import NetSpec, build_network, local_variant, split_point_names
from fogfleet.workload.dnn.profile import median_ms
from fogfleet.workload.dnn.runner import SplitRunner, Stage, sample_frame
from fogfleet.workload.dnn.split import Split, split_all

pytestmark = pytest.mark.timeout(120)

FULL = NetSpec()
# DNNSPLIT.md 3.3's table (fp32 feature maps), with b3, b5, b7 and b8 between its columns
BYTES = {
    "b0": 32 * 112 * 112 * 4,
    "b1": 64 * 112 * 112 * 4,
    "b2": 128 * 56 * 56 * 4,
    "b3": 128 * 56 * 56 * 4,
    "b4": 256 * 28 * 28 * 4,
    "b5": 256 * 28 * 28 * 4,
    "b6": 512 * 14 * 14 * 4,
    "bneck": 8 * 14 * 14 * 4,
    "b7": 512 * 14 * 14 * 4,
    "b8": 1024 * 7 * 7 * 4,
    "b9": 1024 * 7 * 7 * 4,
}


@pytest.fixture(scope="module")
def model() -> onnx.ModelProto:
    return build_network(FULL)


@pytest.fixture(scope="module")
def splits(model: onnx.ModelProto) -> tuple[Split, ...]:
    return split_all(model, split_point_names(FULL))


def test_full_size_split_points_cross_the_bytes_dnnsplit_measured(
    splits: tuple[Split, ...],
) -> None:
    assert {s.name: s.tensor_bytes for s in splits} == BYTES
    assert BYTES["b6"] == 401_408 and BYTES["bneck"] == 6_272


def test_full_size_head_then_tail_is_the_whole_network_exactly(
    model: onnx.ModelProto, splits: tuple[Split, ...]
) -> None:
    frame = sample_frame(FULL)
    whole = Stage.of(model)(frame)
    diffs = {s.name: float(np.max(np.abs(SplitRunner.of(s)(frame) - whole))) for s in splits}
    assert diffs == dict.fromkeys(BYTES, 0.0)


def test_the_local_variant_costs_far_less_than_the_whole_network(model: onnx.ModelProto) -> None:
    frame = sample_frame(FULL)
    full = Stage.of(model)
    full_ms = median_ms(lambda: full(frame), runs=3, warmup=1)
    local = Stage.of(build_network(local_variant(FULL)))
    local_ms = median_ms(lambda: local(frame), runs=3, warmup=1)
    assert local_ms * 3 < full_ms, (local_ms, full_ms)
