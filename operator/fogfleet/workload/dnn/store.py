"""Write the models a split module runs, with every weight stored once (image build time).

The head and the tail of every split point hold the whole network's very initialisers
(``split.py`` extracts, it does not rebuild), so saving each half whole would store the
network's 9.4 MB about 2 x 11 times. Instead every initialiser goes once into ``WEIGHTS``
(ONNX *external data*: a tensor names a file, an offset and a length) and each model file
holds only its graph and those references; onnxruntime reads them relative to the model's
folder. The issue's budget is the image's growth (< 150 MB, issue 48's targets), most of it
onnxruntime and numpy.

Files (``layout.py``): ``full.onnx`` (action 0 on the tail node), ``local.onnx`` (the local
model, action n+1), ``<split>.head.onnx`` and ``<split>.tail.onnx`` per split point,
``weights.bin``.
Only this module and the other build-time ones import onnx; the image's runtime reads the
files with onnxruntime alone (``sessions.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import onnx
from onnx import TensorProto, numpy_helper

from .layout import FULL_FILE, LOCAL_FILE, WEIGHTS, head_file, tail_file
from .network import NetSpec, build_network, local_variant, split_point_names
from .split import split_all

__all__ = ["write_models"]

ALIGN = 64  # each tensor starts on a 64-byte boundary (aligned reads, mmap-friendly)


class _Weights:
    """``WEIGHTS`` as it is written: each tensor's (offset, length) by a key."""

    def __init__(self, out: BinaryIO) -> None:
        self.out = out
        self.where: dict[str, tuple[int, int]] = {}

    def place(self, key: str, tensor: TensorProto) -> tuple[int, int]:
        if key not in self.where:
            data = numpy_helper.to_array(tensor).tobytes()
            offset = -(-self.out.tell() // ALIGN) * ALIGN
            self.out.write(b"\0" * (offset - self.out.tell()))
            self.out.write(data)
            self.where[key] = (offset, len(data))
        return self.where[key]

    def refer(self, model: onnx.ModelProto, prefix: str = "") -> onnx.ModelProto:
        """``model`` with every initialiser moved out to the file (written once per key)."""
        out = onnx.ModelProto()
        out.CopyFrom(model)
        for t in out.graph.initializer:
            offset, length = self.place(prefix + t.name, t)
            dims, dtype, name = list(t.dims), t.data_type, t.name
            t.Clear()
            t.name, t.data_type = name, dtype
            t.dims.extend(dims)
            t.data_location = TensorProto.EXTERNAL
            for k, v in (("location", WEIGHTS), ("offset", offset), ("length", length)):
                entry = t.external_data.add()
                entry.key, entry.value = k, str(v)
        return out


def write_models(spec: NetSpec, out: Path) -> tuple[str, ...]:
    """Every model of ``spec`` into ``out`` (created); the split points' names."""
    out.mkdir(parents=True, exist_ok=True)
    model = build_network(spec)
    names = split_point_names(spec)
    with (out / WEIGHTS).open("wb") as f:
        weights = _Weights(f)
        onnx.save(weights.refer(model), out / FULL_FILE)
        # the local variant's tensors share the big network's names, not its values
        local = build_network(local_variant(spec))
        onnx.save(weights.refer(local, prefix="local/"), out / LOCAL_FILE)
        for split in split_all(model, names):
            onnx.save(weights.refer(split.head), out / head_file(split.name))
            onnx.save(weights.refer(split.tail), out / tail_file(split.name))
    return names
