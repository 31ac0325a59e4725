"""The small network (smallnet.SMALL), its split points and a frame, built once per session."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from smallnet import SMALL

from fogfleet.workload.dnn.network import build_network, split_point_names
from fogfleet.workload.dnn.runner import sample_frame
from fogfleet.workload.dnn.split import Split, split_all


@pytest.fixture(scope="session")
def small_model() -> onnx.ModelProto:
    return build_network(SMALL)


@pytest.fixture(scope="session")
def small_splits(small_model: onnx.ModelProto) -> dict[str, Split]:
    return {s.name: s for s in split_all(small_model, split_point_names(SMALL))}


@pytest.fixture(scope="session")
def frame() -> np.ndarray:
    return sample_frame(SMALL)
