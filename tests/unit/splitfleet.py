"""A warehouse whose pose estimator is a split network (``SoftwareModule.spec.dnn``, issue
48) on robots 25 times slower than the reference core: the planner's and the renderer's tests
share it."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from fogfleet.api.loader import Catalog, load_paths, parse_object

WAREHOUSE = Path(__file__).resolve().parents[2] / "manifests" / "examples" / "warehouse"
HPE = "human-pose-estimation"
ROBOT_SPEED = 0.04  # a robot core 25 times slower than the reference core

# DNNSPLIT.md 3.3's network: a MobileNet-like CNN with a bottleneck after block 6
DNN: dict[str, Any] = {
    "spotlight": "time",
    "minAccuracy": 0.8,
    "inputBytes": 602112,
    "outputBytes": 4000,
    "accuracy": 0.92,
    "fullMillis": 3.8,
    "splitPoints": [
        {"name": "b6", "headMillis": 2.0, "tailMillis": 1.2, "tensorBytes": 401408},
        {"name": "bneck", "headMillis": 2.0, "tailMillis": 1.2, "tensorBytes": 6272},
    ],
    "localModel": {"name": "tiny", "robotMillis": 0.4, "accuracy": 0.61},
}


def split_catalog(
    dnn: dict[str, Any],
    wifi: dict[str, float] | None = None,
    profiling: dict[str, Any] | None = None,
) -> Catalog:
    """The warehouse with human-pose-estimation as a split network and robots 25x slower
    (``profiling``: its spec.profiling)."""
    catalog = load_paths([WAREHOUSE])
    for key, node in list(catalog.nodes.items()):
        if node.spec.tier.value != "robot":
            continue
        raw = json.loads(node.model_dump_json(by_alias=True, exclude_none=True))
        raw["spec"]["speedFactor"] = ROBOT_SPEED
        if wifi is not None:
            raw["spec"]["network"] = [{"type": "wifi", **wifi}]
        catalog.nodes[key] = parse_object(raw)  # type: ignore[assignment]
    key = next(k for k in catalog.modules if k[1] == HPE)
    raw = json.loads(catalog.modules[key].model_dump_json(by_alias=True, exclude_none=True))
    raw["spec"].pop("profile")
    raw["spec"].pop("fallback", None)
    raw["spec"]["dnn"] = copy.deepcopy(dnn)
    if profiling is not None:
        raw["spec"]["profiling"] = profiling
    catalog.modules[key] = parse_object(raw)  # type: ignore[assignment]
    return catalog
