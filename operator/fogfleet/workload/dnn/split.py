"""Cut a network at each of its split points into a *head* (robot) and a *tail* (off-board).

RoboEC2's actions ``a = 1..n`` (roboec2-dnn-offloading, eq. 2) run the layers up to split
point ``a`` on the robot and the rest off-board; the tensor at the cut crosses the link. Both
halves are taken out of the whole model with onnx's own extractor (``onnx.utils.Extractor``,
what ``onnx.utils.extract_model`` does between files, here in memory): the head from the input
to the split point's tensor, the tail from that tensor to the output. Nothing is re-built, so
the two halves hold the whole network's very nodes and weights, and head then tail computes
the whole network's output exactly (``DNNSPLIT.md`` 3.3 and 3.4, item 1). The extracted
models keep the whole model's IR version (the pin onnxruntime needs).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import onnx
from onnx import helper, shape_inference
from onnx.utils import Extractor

from .network import INPUT, OUTPUT

__all__ = ["Split", "split_all", "split_at", "tensor_bytes"]


@dataclass(frozen=True)
class Split:
    """One split point: its name, the head and tail models, and the tensor that crosses
    (its shape and element type, as declared by the head's output)."""

    name: str
    head: onnx.ModelProto
    tail: onnx.ModelProto
    shape: tuple[int, ...]
    dtype: np.dtype[np.generic]

    @property
    def tensor_bytes(self) -> int:
        """What crosses the link per frame: prod(shape) x the element's size."""
        return int(np.prod(self.shape)) * self.dtype.itemsize


def tensor_bytes(value: onnx.ValueInfoProto) -> int:
    """A declared tensor's size in bytes (every dimension must be fixed)."""
    shape, dtype = _shape_and_dtype(value)
    return int(np.prod(shape)) * dtype.itemsize


def _shape_and_dtype(value: onnx.ValueInfoProto) -> tuple[tuple[int, ...], np.dtype[np.generic]]:
    t = value.type.tensor_type
    dims = tuple(d.dim_value for d in t.shape.dim)
    if any(d <= 0 for d in dims) or any(d.HasField("dim_param") for d in t.shape.dim):
        raise ValueError(f"tensor {value.name!r}: every dimension must be fixed, got {dims}")
    return dims, np.dtype(helper.tensor_dtype_to_np_dtype(t.elem_type))


def split_all(model: onnx.ModelProto, names: Sequence[str]) -> tuple[Split, ...]:
    """Cut ``model`` at each named tensor, in the order given."""
    extractor = Extractor(shape_inference.infer_shapes(model, strict_mode=True))
    return tuple(_cut(extractor, name) for name in names)


def split_at(model: onnx.ModelProto, name: str) -> Split:
    """Cut ``model`` at one named tensor."""
    return split_all(model, [name])[0]


def _cut(extractor: Extractor, name: str) -> Split:
    if name not in extractor.value_infos:
        raise ValueError(f"no tensor {name!r} to cut at in {extractor.graph.name!r}")
    head = extractor.extract_model([INPUT], [name])
    tail = extractor.extract_model([name], [OUTPUT])
    for half in (head, tail):
        half.graph.name = f"{extractor.graph.name}.{name}.{'head' if half is head else 'tail'}"
        onnx.checker.check_model(half)
    shape, dtype = _shape_and_dtype(head.graph.output[0])
    return Split(name=name, head=head, tail=tail, shape=shape, dtype=dtype)
