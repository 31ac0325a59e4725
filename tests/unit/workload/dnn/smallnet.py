"""The small network the dnn unit tests share: 32x32 frames at width 0.25, ten classes (the
unit tier's 1 s per test; the full-size network is tested in tests/integration)."""

from __future__ import annotations

from fogfleet.workload.dnn.network import NetSpec

SMALL = NetSpec(input_size=32, width=0.25, classes=10, seed=7)
