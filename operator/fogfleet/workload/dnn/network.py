"""A real, small CNN that can be cut in two, built from a seed (nothing downloaded).

``DNNSPLIT.md`` 3.3: a MobileNet-v1-like network (a stem convolution, then depthwise-separable
blocks that halve the feature map while widening it, global average pooling, one fully
connected layer) written with ``onnx.helper`` and numpy random weights drawn from a seed, so
the same seed gives the same model byte for byte. A 1x1-convolution *bottleneck*
(512 -> 8 -> 512 at width 1) follows block 6: split computing's injected bottleneck (Shi et
al., arXiv 1903.03472), which makes an interior split pay off, because early feature maps are
larger than the input. The weights are random, so the network has no accuracy: its times and
tensor sizes are real, and accuracy is declared per variant, as RoboEC2 does
(roboec2-dnn-offloading, eq. 6).

The input is a camera frame, ``uint8`` ``(1, H, W, 3)``: what crosses the link for full
offload (RoboEC2's ``Data^0``); the graph casts, scales and transposes it itself. The output is
``float32`` logits ``(1, classes)``.

Every tensor that can be cut is named after its split point: ``b0`` (the stem), ``b1`` ...
``b9`` (the blocks' outputs) and ``bneck`` (the bottleneck's narrow tensor). The local variant
(RoboEC2's lightweight model ``a = n+1``) is the same network at width 0.25.

``ir_version`` is pinned: onnx 1.23 writes IR 14, which onnxruntime 1.31 refuses
("Unsupported model IR version: 14"; ``DNNSPLIT.md`` 3.3, pitfall).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

__all__ = [
    "BLOCKS",
    "BOTTLENECK_AFTER",
    "INPUT",
    "IR_VERSION",
    "LOCAL_WIDTH",
    "OPSET",
    "OUTPUT",
    "NetSpec",
    "build_network",
    "local_variant",
    "parameter_count",
    "split_point_names",
]

IR_VERSION = 10  # onnxruntime 1.31 loads at most IR 13; onnx 1.23 would write 14
OPSET = 17
INPUT = "image"
OUTPUT = "logits"
STEM_CHANNELS = 32
# (output channels at width 1, stride) of the depthwise-separable blocks b1..b9: MobileNet-v1's
# sequence with four of its five 512-channel blocks left out, to keep the network small
BLOCKS: tuple[tuple[int, int], ...] = (
    (64, 1),
    (128, 2),
    (128, 1),
    (256, 2),
    (256, 1),
    (512, 2),
    (512, 1),
    (1024, 2),
    (1024, 1),
)
BOTTLENECK_AFTER = 6  # the bottleneck follows block 6 (DNNSPLIT.md 3.3)
BOTTLENECK_NAME = "bneck"
LOCAL_WIDTH = 0.25
STRIDE_PRODUCT = 2 * 2 * 2 * 2 * 2  # the stem and four blocks halve the feature map
MIN_CHANNELS = 8


@dataclass(frozen=True)
class NetSpec:
    """What a network is built from: the frame's side in pixels (a multiple of 32), the width
    multiplier of every layer's channels, the classes, the bottleneck's channels (0: none)
    and the seed of its weights."""

    input_size: int = 224
    width: float = 1.0
    classes: int = 1000
    bottleneck: int = 8
    seed: int = 0
    name: str = "mobilenet-like"

    def __post_init__(self) -> None:
        if self.input_size < STRIDE_PRODUCT or self.input_size % STRIDE_PRODUCT:
            raise ValueError(f"input size {self.input_size}: a multiple of {STRIDE_PRODUCT}")
        if not 0 < self.width <= 4:
            raise ValueError(f"width {self.width}: above 0, at most 4")
        if self.classes < 1 or self.bottleneck < 0:
            raise ValueError("classes at least 1, bottleneck channels 0 or more")

    def channels(self, at_width_1: int) -> int:
        """A layer's channels at this width (at least 8)."""
        return max(MIN_CHANNELS, int(at_width_1 * self.width))


def local_variant(spec: NetSpec) -> NetSpec:
    """The robot's lightweight model: the same network at width 0.25, from the same seed."""
    width = spec.width * LOCAL_WIDTH
    return replace(spec, width=width, name=f"{spec.name}-w{width:g}")


def split_point_names(spec: NetSpec) -> tuple[str, ...]:
    """The split points in order from input to output (each is the name of its tensor)."""
    names = [f"b{i}" for i in range(len(BLOCKS) + 1)]
    if spec.bottleneck:
        names.insert(BOTTLENECK_AFTER + 1, BOTTLENECK_NAME)
    return tuple(names)


class _Graph:
    """Nodes and initialisers in the order they are made; weights drawn from one generator,
    in that order, so a seed fixes every byte."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.nodes: list[onnx.NodeProto] = []
        self.weights: list[onnx.TensorProto] = []

    def constant(self, name: str, value: np.ndarray) -> str:
        self.weights.append(numpy_helper.from_array(value, name))
        return name

    def conv_relu(
        self,
        x: str,
        out: str,
        c_in: int,
        c_out: int,
        k: int,
        stride: int = 1,
        depthwise: bool = False,
    ) -> str:
        """A convolution (batch norm folded into its bias, as after training) and a ReLU."""
        group = c_in if depthwise else 1
        fan_in = (c_in // group) * k * k
        w = self.rng.normal(0.0, np.sqrt(2.0 / fan_in), (c_out, c_in // group, k, k))
        b = self.rng.normal(0.0, 0.01, c_out)
        wn = self.constant(f"{out}.w", w.astype(np.float32))
        bn = self.constant(f"{out}.b", b.astype(np.float32))
        pad = k // 2
        self.nodes.append(
            helper.make_node(
                "Conv",
                [x, wn, bn],
                [f"{out}.conv"],
                name=f"{out}.conv",
                kernel_shape=[k, k],
                strides=[stride, stride],
                pads=[pad] * 4,
                group=group,
            )
        )
        self.nodes.append(helper.make_node("Relu", [f"{out}.conv"], [out], name=f"{out}.relu"))
        return out


def build_network(spec: NetSpec) -> onnx.ModelProto:
    """The whole network for ``spec``, checked by onnx; the same spec gives the same bytes."""
    g = _Graph(np.random.default_rng(spec.seed))
    # the frame: uint8 NHWC in 0..255 -> float32 NCHW in -1..1
    g.nodes += [
        helper.make_node("Cast", [INPUT], ["pre.f"], name="pre.cast", to=TensorProto.FLOAT),
        helper.make_node(
            "Mul",
            ["pre.f", g.constant("pre.scale", np.array([1 / 127.5], np.float32))],
            ["pre.s"],
            name="pre.scale",
        ),
        helper.make_node(
            "Add",
            ["pre.s", g.constant("pre.shift", np.array([-1.0], np.float32))],
            ["pre.n"],
            name="pre.shift",
        ),
        helper.make_node("Transpose", ["pre.n"], ["pre.nchw"], name="pre.nchw", perm=[0, 3, 1, 2]),
    ]
    c = spec.channels(STEM_CHANNELS)
    x = g.conv_relu("pre.nchw", "b0", 3, c, 3, stride=2)
    for i, (c_out_1, stride) in enumerate(BLOCKS, start=1):
        c_out = spec.channels(c_out_1)
        x = g.conv_relu(x, f"b{i}.dw", c, c, 3, stride=stride, depthwise=True)
        x = g.conv_relu(x, f"b{i}", c, c_out, 1)
        c = c_out
        if i == BOTTLENECK_AFTER and spec.bottleneck:
            x = g.conv_relu(x, BOTTLENECK_NAME, c, spec.bottleneck, 1)
            x = g.conv_relu(x, f"{BOTTLENECK_NAME}.expand", spec.bottleneck, c, 1)
    fc_w = g.rng.normal(0.0, np.sqrt(1.0 / c), (spec.classes, c)).astype(np.float32)
    g.nodes += [
        helper.make_node("GlobalAveragePool", [x], ["cls.pool"], name="cls.pool"),
        helper.make_node("Flatten", ["cls.pool"], ["cls.flat"], name="cls.flat", axis=1),
        helper.make_node(
            "Gemm",
            [
                "cls.flat",
                g.constant("fc.w", fc_w),
                g.constant("fc.b", np.zeros(spec.classes, np.float32)),
            ],
            [OUTPUT],
            name="fc",
            transB=1,
        ),
    ]
    side = spec.input_size
    graph = helper.make_graph(
        g.nodes,
        spec.name,
        [helper.make_tensor_value_info(INPUT, TensorProto.UINT8, [1, side, side, 3])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, [1, spec.classes])],
        initializer=g.weights,
    )
    model = helper.make_model(
        graph,
        ir_version=IR_VERSION,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="fogfleet.workload.dnn",
        doc_string=f"{spec} (random weights: no accuracy)",
    )
    onnx.checker.check_model(model)
    return model


def parameter_count(model: onnx.ModelProto) -> int:
    """The weights' count (the preprocessing constants included)."""
    return sum(int(np.prod(t.dims)) for t in model.graph.initializer)
