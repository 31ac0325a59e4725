"""What the pods of a split network (``SoftwareModule.spec.dnn``, issue 48) are told
(``contract.dnn``): the network, its bounds, the speeds of the robot and of the tail's node,
and the action the planner took (DNNSPLIT.md 3.2). Its robot runs the ``head`` pod (the frames,
the head of the split or the local model, RoboEC2's rule per frame); the node the plan chose
runs the ``tail`` pod. A plan that keeps the module on its robot runs the head alone, with the
local model."""

from __future__ import annotations

from typing import Any

from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.contract.dnn import (
    KEY_PLANNED_ACTION,
    KEY_ROBOT_FACTOR,
    KEY_TAIL_FACTOR,
    ROLE_HEAD,
    ROLE_TAIL,
)
from fogfleet.contract.dnnsplit import DnnSplit, action_name
from fogfleet.domain.dnnpairs import kind_of, network_on
from fogfleet.domain.problem import Problem

__all__ = ["ROLE_HEAD", "ROLE_TAIL", "split_body"]


def split_body(problem: Problem, module: SoftwareModule, i: int, j: int) -> dict[str, Any]:
    """The ``dnn`` key of the module spec its pods read: ``spec.dnn`` with alpha resolved,
    each side's time per reference-core second (1 / speedFactor), and the planned action of
    instance ``i`` with its tail on node ``j`` (its robot: the local model alone). Where a
    side's hardware type has a profile (``spec.dnn.profiles``, or measured by profiling), the
    times are the network's on the robot and on the tail node as the planner used them
    (``domain.dnnpairs.network_on``), with that side's factor 1."""
    dnn = module.spec.dnn
    assert dnn is not None
    home = int(problem.home[i])
    index = -1 if problem.dnn_action is None else int(problem.dnn_action[i, j])
    on = network_on(dnn, float(problem.cycle[i]), kind_of(problem.nodes[home]),
                    kind_of(problem.nodes[j]))  # fmt: skip
    if index < 0 or isinstance(on, str):
        raise ValueError(f"{problem.label(i)} is not planned as a split network on node {j}")
    body = dnn.wire()
    body.pop("profiles", None)
    if on.measured:
        body |= _times(on.model)
    body |= {
        "maxLatencyMillis": on.model.max_latency_s * 1e3,
        KEY_ROBOT_FACTOR: on.robot_factor,
        KEY_PLANNED_ACTION: action_name(on.model, index),
    }
    if j != home:
        body[KEY_TAIL_FACTOR] = on.tail_factor
    return body


def _times(model: DnnSplit) -> dict[str, Any]:
    """The times and bytes of ``model`` as ``spec.dnn`` writes them (milliseconds, bytes)."""
    return {
        "inputBytes": model.input_bytes,
        "outputBytes": model.output_bytes,
        "fullMillis": round(model.full_s * 1e3, 6),
        "splitPoints": [
            {
                "name": p.name,
                "headMillis": round(p.head_s * 1e3, 6),
                "tailMillis": round(p.tail_s * 1e3, 6),
                "tensorBytes": p.tensor_bytes,
            }
            for p in model.split_points
        ],
        "localModel": {
            "name": model.local_name,
            "robotMillis": round(model.local_s * 1e3, 6),
            "accuracy": model.local_accuracy,
        },
    }
