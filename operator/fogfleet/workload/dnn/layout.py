"""The model files' names in a model folder (``store.py`` writes them at image build time,
``sessions.py`` reads them at run time; this module imports nothing, so both can name them)."""

from __future__ import annotations

__all__ = ["FULL_FILE", "LOCAL_FILE", "WEIGHTS", "head_file", "tail_file"]

WEIGHTS = "weights.bin"  # every initialiser, once (ONNX external data)
FULL_FILE = "full.onnx"  # action 0, on the tail node
LOCAL_FILE = "local.onnx"  # the local model, action n+1, on the robot


def head_file(split: str) -> str:
    """A split point's head (the robot's part)."""
    return f"{split}.head.onnx"


def tail_file(split: str) -> str:
    """A split point's tail (the off-board part)."""
    return f"{split}.tail.onnx"
