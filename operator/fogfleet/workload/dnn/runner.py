"""onnxruntime sessions for the whole network, its local variant and each split's two halves.

One thread per session (``intra_op_num_threads=1``, sequential execution): times are "on the
measuring core", the reference core the SoftwareModule's ``dnn`` field declares them on
(``DNNSPLIT.md`` 3.2), which fogfleet scales per node by its speed factors.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import onnx
import onnxruntime as ort

from .network import NetSpec
from .split import Split

__all__ = ["SplitRunner", "Stage", "sample_frame", "session"]


def session(model: onnx.ModelProto) -> ort.InferenceSession:
    """A single-threaded CPU session of ``model``."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.log_severity_level = 3  # warnings about thread affinity are noise here
    return ort.InferenceSession(
        model.SerializeToString(), sess_options=options, providers=["CPUExecutionProvider"]
    )


@dataclass(frozen=True)
class Stage:
    """A model with one input and one output, ready to run."""

    session: ort.InferenceSession
    input_name: str
    output_name: str

    @classmethod
    def of(cls, model: onnx.ModelProto) -> Stage:
        return cls(session(model), model.graph.input[0].name, model.graph.output[0].name)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = self.session.run([self.output_name], {self.input_name: x})[0]
        return np.asarray(out)


@dataclass(frozen=True)
class SplitRunner:
    """A split point's head (on the robot) and tail (off-board)."""

    name: str
    head: Stage
    tail: Stage

    @classmethod
    def of(cls, split: Split) -> SplitRunner:
        return cls(split.name, Stage.of(split.head), Stage.of(split.tail))

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """Head then tail: the whole network's output, computed in two parts."""
        return self.tail(self.head(frame))

    @staticmethod
    def all(splits: Sequence[Split]) -> tuple[SplitRunner, ...]:
        return tuple(SplitRunner.of(s) for s in splits)


def sample_frame(spec: NetSpec, seed: int = 1) -> np.ndarray:
    """A camera frame of random pixels, shaped as ``spec``'s input (``uint8``, NHWC)."""
    rng = np.random.default_rng(seed)
    side = spec.input_size
    frame: np.ndarray = rng.integers(0, 256, (1, side, side, 3), dtype=np.uint8)
    return frame
