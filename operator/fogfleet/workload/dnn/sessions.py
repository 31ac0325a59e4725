"""The split module's networks at run time, read from the image's model files with onnxruntime
alone (no onnx: the image's final stage does not ship it; ``store.py`` wrote the files).

One thread per session (``session_options``), as the profile was measured (``runner.py``):
the times the head measures are then comparable with the declared ones, which are per core.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort

from fogfleet.contract.env import ENV_DNN_MODELS

from .layout import FULL_FILE, LOCAL_FILE, head_file, tail_file

__all__ = [
    "DEFAULT_MODELS",
    "Net",
    "RobotNets",
    "TailNets",
    "models_folder",
    "session_options",
]

DEFAULT_MODELS = Path("/opt/fogfleet-dnn/models")  # where the image's build stage wrote them


def models_folder(env: Mapping[str, str]) -> Path:
    """Where the image's build stage wrote the models (``FOGFLEET_DNN_MODELS`` overrides)."""
    return Path(env.get(ENV_DNN_MODELS) or DEFAULT_MODELS)


def session_options() -> ort.SessionOptions:
    """One intra-op and one inter-op thread, sequential: a network on one core."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.log_severity_level = 3  # warnings about thread affinity are noise here
    return options


@dataclass(frozen=True)
class Net:
    """One model file, loaded: its input's shape and type, and a call."""

    session: ort.InferenceSession
    input_name: str
    input_shape: tuple[int, ...]
    input_dtype: np.dtype[np.generic]

    @classmethod
    def load(cls, path: Path) -> Net:
        if not path.is_file():
            raise FileNotFoundError(f"no model {path.name} in {path.parent}")
        s = ort.InferenceSession(
            os.fspath(path), sess_options=session_options(), providers=["CPUExecutionProvider"]
        )
        inp = s.get_inputs()[0]
        dtype = np.dtype(np.uint8 if inp.type == "tensor(uint8)" else np.float32)
        net = cls(s, inp.name, tuple(int(d) for d in inp.shape), dtype)
        net(np.zeros(net.input_shape, dtype))  # the first run allocates: not a frame's time
        return net

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.session.run(None, {self.input_name: x})[0])

    def from_bytes(self, data: bytes) -> np.ndarray:
        """A tensor that crossed the link, back in this model's input's shape (ValueError if
        the byte count does not fit: a head of another split point sent it)."""
        want = int(np.prod(self.input_shape)) * self.input_dtype.itemsize
        if len(data) != want:
            raise ValueError(f"{len(data)} bytes for an input of {want} {self.input_shape}")
        return np.frombuffer(data, self.input_dtype).reshape(self.input_shape)


class RobotNets:
    """The robot's side: every split point's head and the local model (both resident: the
    local model answers the moment the link fails, RoboEC2 Section IV-A)."""

    def __init__(
        self, folder: Path, splits: Sequence[str], seed: int = 0, whole: bool = False
    ) -> None:
        self.heads = {k: Net.load(folder / head_file(n)) for k, n in enumerate(splits, start=1)}
        self.local_net = Net.load(folder / LOCAL_FILE)
        # the whole network, for a module run whole on its robot (``whole.Whole.ROBOT``)
        self.whole_net = Net.load(folder / FULL_FILE) if whole else None
        self.rng = np.random.default_rng(seed)

    def capture(self, frame: int) -> np.ndarray:
        """A synthetic camera frame (uint8, NHWC, the local model's input shape)."""
        shape = self.local_net.input_shape
        out: np.ndarray = self.rng.integers(0, 256, shape, dtype=np.uint8)
        return out

    def head(self, index: int, frame: np.ndarray) -> bytes:
        """What crosses for action ``index``: the raw frame (0) or the split's tensor."""
        if index == 0:
            return frame.tobytes()
        return self.heads[index](frame).tobytes()

    def local(self, frame: np.ndarray) -> bytes:
        return self.local_net(frame).tobytes()

    def whole(self, frame: np.ndarray) -> bytes:
        """The whole network's answer, on the robot (loaded only when asked: ``whole``)."""
        if self.whole_net is None:
            raise RuntimeError("the whole network was not loaded (RobotNets(whole=True))")
        return self.whole_net(frame).tobytes()


class TailNets:
    """The off-board side: the whole network (action 0) and every split point's tail."""

    def __init__(self, folder: Path, splits: Sequence[str]) -> None:
        self.nets = {0: Net.load(folder / FULL_FILE)}
        self.nets |= {k: Net.load(folder / tail_file(n)) for k, n in enumerate(splits, start=1)}

    def tail(self, index: int, data: bytes) -> bytes:
        """The answer to what a head sent for action ``index`` (KeyError: no such action)."""
        net = self.nets[index]
        return net(net.from_bytes(data)).tobytes()
