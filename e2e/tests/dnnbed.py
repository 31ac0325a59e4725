"""A fleet of one split pose estimator per robot on the bed's real nodes (issue 48), and what
its head says: shared by the split network's e2e tests and ``make bench-split``.

The declared times are this machine's profile (``python -m fogfleet.workload.dnn profile``,
224x224, one thread: DNNSPLIT.md 3.3); the accuracies are declared (the image's network has
random weights).
"""

from __future__ import annotations

from typing import Any

from e2e.portable.metrics import read
from e2e.tests.rosbed import bed_objects, ros_module

__all__ = [
    "ALPHA_MS",
    "DNN",
    "FLEET",
    "MODULE",
    "SLOW",
    "frames_by_action",
    "head_action",
    "profiled_objects",
    "split_objects",
]

FLEET = "splitfleet"
MODULE = "pose"
ALPHA_MS = 100  # the frame's bound, = the cycle
SLOW = {"rate_mbit": 5.0, "delay_ms": 15.0}  # the raw frame alone takes 241 ms: only bneck fits
DNN: dict[str, Any] = {
    "spotlight": "time",
    "minAccuracy": 0.8,
    "inputBytes": 150528,
    "outputBytes": 4000,
    "accuracy": 0.92,
    "fullMillis": 7.9,
    "splitPoints": [
        {"name": "b6", "headMillis": 4.7, "tailMillis": 3.0, "tensorBytes": 401408},
        {"name": "bneck", "headMillis": 4.6, "tailMillis": 2.9, "tensorBytes": 6272},
    ],
    "localModel": {"name": "mobilenet-w0.25", "robotMillis": 0.9, "accuracy": 0.61},
}


def split_objects(ns: str, **dnn: Any) -> list[dict[str, Any]]:
    """The bed's nodes and a fleet of one split pose estimator per robot (``dnn`` on top of
    ``DNN``)."""
    pose = ros_module(MODULE, ns, cycle_ms=ALPHA_MS, taxonomy=("continuous", "soft", "relevant"),
                      subscribes=[], publishes=[("poses", 4000, 10)], profile=[])  # fmt: skip
    del pose["spec"]["profile"]
    pose["spec"]["dnn"] = DNN | dnn
    pose["spec"]["resources"]["memory"] = "384Mi"  # onnxruntime, the heads and ROS 2
    return bed_objects(ns, FLEET, [pose])


def profiled_objects(ns: str, frames: int) -> list[dict[str, Any]]:
    """The same fleet with no time or byte count declared: ``profiling.mode: auto`` (one Job
    per hardware type timing ``frames`` frames of every part) measures them."""
    objects = split_objects(ns)
    pose = next(o for o in objects if o["kind"] == "SoftwareModule")
    dnn = pose["spec"]["dnn"]
    for key in ("inputBytes", "outputBytes", "fullMillis"):
        del dnn[key]
    dnn["localModel"] = {k: v for k, v in dnn["localModel"].items() if k != "robotMillis"}
    dnn["splitPoints"] = [{"name": p["name"]} for p in dnn["splitPoints"]]
    pose["spec"]["profiling"] = {"mode": "auto", "cycles": frames, "timeoutSeconds": 180}
    return objects


def head_action(url: str) -> str:
    """The action the head runs now ("" while it cannot be read)."""
    try:
        series = read(url).series
    except OSError:
        return ""
    return next((lb["action"] for n, lb, v in series if n == "fogfleet_dnn_action" and v == 1), "")


def frames_by_action(url: str) -> dict[str, float]:
    """The head's frames so far per action, whoever answered them."""
    return read(url).by("fogfleet_dnn_frames_total", "action")
