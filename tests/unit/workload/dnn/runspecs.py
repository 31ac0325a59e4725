"""A split module's spec as the renderer writes it (contract.dnn), shared by the runtime's tests."""

from __future__ import annotations

import copy
from typing import Any

SPEC: dict[str, Any] = {
    "cycleTimeMillis": 100,
    "topics": {"publishes": [{"name": "objects", "sizeBytes": 256, "rateHz": 10}]},
    "dnn": {
        "spotlight": "time",
        "maxLatencyMillis": 50,
        "minAccuracy": 0.8,
        "inputBytes": 150528,
        "outputBytes": 4000,
        "accuracy": 0.92,
        "fullMillis": 3.8,
        "splitPoints": [
            {"name": "b6", "headMillis": 2.0, "tailMillis": 1.2, "tensorBytes": 401408},
            {"name": "bneck", "headMillis": 2.0, "tailMillis": 1.2, "tensorBytes": "6272"},
        ],
        "localModel": {"name": "tiny", "robotMillis": 0.4, "accuracy": 0.61},
        "robotFactor": 1,
        "tailFactor": 1,
        "plannedAction": "bneck",
    },
}


def spec(**dnn: Any) -> dict[str, Any]:
    """``SPEC`` with some of its ``dnn`` keys replaced (None: removed)."""
    out = copy.deepcopy(SPEC)
    for k, v in dnn.items():
        if v is None:
            out["dnn"].pop(k, None)
        else:
            out["dnn"][k] = v
    return out
