"""Instance states from pod lists (pure; no cluster): the protocol's Pending rule."""

from __future__ import annotations

from typing import Any

from e2e.bench.real.binding import instance_states


def _pod(module: str, robot: str, *conditions: tuple[str, str, str], **meta: Any) -> dict[str, Any]:
    return {
        "metadata": {
            "labels": {
                "fogfleet.io/module": module,
                "fogfleet.io/robot": robot,
                **meta.pop("labels", {}),
            },
            **meta,
        },
        "status": {"conditions": [{"type": t, "status": s, "reason": r} for t, s, r in conditions]},
    }


READY = ("Ready", "True", "")
UNSCHEDULABLE = ("PodScheduled", "False", "Unschedulable")
BOUND = ("PodScheduled", "True", "")


def test_ready_unschedulable_and_starting_pods_are_told_apart() -> None:
    pods = [
        _pod("pose", "r1", BOUND, READY),
        _pod("pose", "r2", UNSCHEDULABLE),
        _pod("seg", "r1", BOUND, ("Ready", "False", "ContainersNotReady")),
        _pod("seg", "r2"),  # just created: no condition yet
        {"metadata": {"labels": {"app": "discovery"}}, "status": {}},  # not a module
    ]
    assert instance_states(pods) == {
        ("pose", "r1"): "Ready",
        ("pose", "r2"): "Unschedulable",
        ("seg", "r1"): "Starting",
        ("seg", "r2"): "Starting",
    }


def test_a_rollouts_old_pod_a_deleted_pod_and_a_standby_do_not_hide_an_instances_state() -> None:
    pods = [
        _pod("pose", "r1", UNSCHEDULABLE),
        _pod("pose", "r1", BOUND, READY),  # the same instance, its other pod Ready
        _pod("seg", "r1", BOUND, READY, deletionTimestamp="2026-11-29T00:00:00Z"),
        _pod("seg", "r1", UNSCHEDULABLE),
        _pod("nav", "r1", BOUND, READY, labels={"app.kubernetes.io/component": "fallback-standby"}),
    ]
    assert instance_states(pods) == {("pose", "r1"): "Ready", ("seg", "r1"): "Unschedulable"}


def test_the_annotations_name_the_instance_when_a_label_had_to_be_shortened() -> None:
    pod = _pod("pose", "r1", UNSCHEDULABLE)
    pod["metadata"]["annotations"] = {"fogfleet.io/robot": "a-robot-name-longer-than-a-label"}
    assert instance_states([pod]) == {("pose", "a-robot-name-longer-than-a-label"): "Unschedulable"}
