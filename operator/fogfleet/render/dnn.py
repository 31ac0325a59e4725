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
from fogfleet.contract.dnnsplit import action_name
from fogfleet.domain.dnnpairs import model_of
from fogfleet.domain.problem import Problem

__all__ = ["ROLE_HEAD", "ROLE_TAIL", "split_body"]


def split_body(problem: Problem, module: SoftwareModule, i: int, j: int) -> dict[str, Any]:
    """The ``dnn`` key of the module spec its pods read: ``spec.dnn`` with alpha resolved,
    each side's time per reference-core second (1 / speedFactor), and the planned action of
    instance ``i`` with its tail on node ``j`` (its robot: the local model alone)."""
    assert module.spec.dnn is not None
    cycle = float(problem.cycle[i])
    model = model_of(module.spec.dnn, cycle)
    home = int(problem.home[i])
    index = -1 if problem.dnn_action is None else int(problem.dnn_action[i, j])
    if index < 0:
        raise ValueError(f"{problem.label(i)} is not planned as a split network on node {j}")
    body = module.spec.dnn.wire() | {
        "maxLatencyMillis": model.max_latency_s * 1e3,
        KEY_ROBOT_FACTOR: 1.0 / max(problem.nodes[home].speed_factor, 1e-6),
        KEY_PLANNED_ACTION: action_name(model, index),
    }
    if j != home:
        body[KEY_TAIL_FACTOR] = 1.0 / max(problem.nodes[j].speed_factor, 1e-6)
    return body
