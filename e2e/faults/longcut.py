"""What test_faults_long_cut reads besides the cut fleet's own counters (cutfleet.py).

A control pod with the bed's default tolerations only, pinned to the cut robot: evicted once
the timeout runs out. The fleet's pods, their containers and a node's taints, as the API
sees them during and after the cut; and one reading of every counter the long cut's figures
need, with what went unanswered between two readings.
"""

from __future__ import annotations

import time
from typing import Any

from e2e.bed.images import PAUSE_REF
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import all_pods
from e2e.faults.cutfleet import input_gaps
from e2e.tests.rosbed import scrape, scrape_series

__all__ = [
    "CONTROL",
    "containers",
    "control_pod",
    "counters",
    "delta",
    "fleet_pods",
    "ready",
    "taints",
    "unanswered",
]

CONTROL = "control-pause"


def control_pod(ns: str, node: str) -> dict[str, Any]:
    """A pod with the bed's default tolerations only (admission adds them): evicted 10 s after
    its node turns unreachable. Restricted Pod Security, like everything else in the bed."""
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": CONTROL, "namespace": ns, "labels": {"app": CONTROL}},
        "spec": {
            "nodeName": node,
            "automountServiceAccountToken": False,
            "terminationGracePeriodSeconds": 1,
            "securityContext": {
                "runAsNonRoot": True,
                "runAsUser": 65532,
                "seccompProfile": {"type": "RuntimeDefault"},
            },
            "containers": [
                {
                    "name": "pause",
                    "image": PAUSE_REF,
                    "imagePullPolicy": "Never",
                    "securityContext": {
                        "allowPrivilegeEscalation": False,
                        "capabilities": {"drop": ["ALL"]},
                    },
                }
            ],
        },
    }


def ready(pod: dict[str, Any]) -> bool:
    return any(
        c["type"] == "Ready" and c["status"] == "True"
        for c in (pod.get("status") or {}).get("conditions") or []
    )


def containers(pod: dict[str, Any]) -> dict[str, tuple[str, int]]:
    """container name -> (container ID, restart count)."""
    return {
        c["name"]: (c.get("containerID", ""), c.get("restartCount", 0))
        for c in (pod.get("status") or {}).get("containerStatuses") or []
    }


def fleet_pods(kube: Kube, ns: str) -> dict[str, dict[str, Any]]:
    """Every pod fogfleet made in ``ns`` (modules, standbys, discovery servers), by UID, the
    terminating ones included."""
    return {
        p["metadata"]["uid"]: p
        for p in all_pods(kube, ns)
        if p["metadata"].get("labels", {}).get("app.kubernetes.io/managed-by") == "fogfleet"
    }


def taints(kube: Kube, node: str) -> set[str]:
    spec = kube.kubectl_json("get", "node", node)["spec"]
    return {f"{t['key']}:{t['effect']}" for t in spec.get("taints") or []}


def counters(urls: dict[str, str]) -> dict[str, Any]:
    """One reading of every counter the figures need, with the moment it was taken."""
    safety, camera = urls["safety"], urls["camera"]
    return {
        "t": time.monotonic(),
        "images": scrape_series(camera, "fogfleet_messages_published_total", topic="image"),
        "camera": scrape(camera),
        "safety": scrape(safety),
        "objects": scrape_series(safety, "fogfleet_messages_received_total", topic="objects"),
        "segments": scrape_series(safety, "fogfleet_messages_received_total", topic="segments"),
        "tracks": scrape_series(safety, "fogfleet_messages_received_total", topic="tracks"),
        "objects_gaps": input_gaps(safety, "objects"),
        "segments_gaps": input_gaps(safety, "segments"),
        "out_of_order": scrape_series(safety, "fogfleet_out_of_order_messages_total"),
        "standby": scrape(urls["standby"]),
        "variant": scrape(urls["variant"]),
    }


def unanswered(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, float, float]:
    """From reading ``a`` to ``b``: camera images, images the safety module got no object
    for, and images it got no segment for beyond the variant's half rate (each of the
    variant's own cycles answers one image of two)."""
    images = b["images"] - a["images"]
    lite = (
        b["variant"]["fogfleet_cycle_time_seconds_count"]
        - a["variant"]["fogfleet_cycle_time_seconds_count"]
    )
    return (
        images,
        images - (b["objects"] - a["objects"]),
        images - lite - (b["segments"] - a["segments"]),
    )


def delta(a: dict[str, Any], b: dict[str, Any], who: str, metric: str) -> float:
    return float(b[who].get(metric, 0.0) - a[who].get(metric, 0.0))
