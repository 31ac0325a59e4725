"""What the renderer and a split module's two pods agree on (issue 48; DNNSPLIT.md 3.2).

A module with ``spec.dnn`` runs as two pods of the ROS 2 workload image, both started as
``python -m fogfleet.workload dnn``; ``FOGFLEET_ROLE`` says which side:

* ``head`` (``ROLE_HEAD``), on the robot: it makes the frames, runs the head of the chosen
  split (or the local model), applies RoboEC2's rule (``contract.dnnsplit``) per frame and
  publishes the answer on the module's first output topic;
* ``tail`` (``ROLE_TAIL``), on the edge or cloud node the planner chose: it runs the tail of
  whatever split a frame names (the whole network for full offload) and answers.

They talk over two topics under the module's name (``tensor_topic``, ``answer_topic``): the
robot's own discovery server keeps each robot's pair apart, so no robot prefix is needed.

``FOGFLEET_MODULE_SPEC`` carries ``spec.dnn`` (camelCase, as the API writes it) under
``SPEC_KEY``, with ``maxLatencyMillis`` always present (the renderer resolves it from the
cycle) and three keys of the plan: ``KEY_ROBOT_FACTOR`` (the robot's time per reference-core
second, 1 / speedFactor), ``KEY_TAIL_FACTOR`` (the planned tail node's) and
``KEY_PLANNED_ACTION`` (the action the planner chose: ``FULL_OFFLOAD``, a split point's name
or the local model's name).
"""

from __future__ import annotations

__all__ = [
    "FULL_OFFLOAD",
    "KEY_PLANNED_ACTION",
    "KEY_ROBOT_FACTOR",
    "KEY_TAIL_FACTOR",
    "ROLE_HEAD",
    "ROLE_TAIL",
    "SPEC_KEY",
    "answer_topic",
    "tensor_topic",
]

ROLE_HEAD = "head"
ROLE_TAIL = "tail"
SPEC_KEY = "dnn"
KEY_ROBOT_FACTOR = "robotFactor"
KEY_TAIL_FACTOR = "tailFactor"
KEY_PLANNED_ACTION = "plannedAction"
FULL_OFFLOAD = "full offload"  # contract.dnnsplit's name of action 0


def _base(module: str) -> str:
    """A ROS 2 name from a module's (Kubernetes names may hold dashes; ROS names may not)."""
    return module.replace("-", "_").strip("/")


def tensor_topic(module: str) -> str:
    """Head -> tail: a frame's tensor (or the raw frame for full offload), and probes."""
    return f"{_base(module)}/dnn/tensor"


def answer_topic(module: str) -> str:
    """Tail -> head: a frame's answer, and the probes' echoes."""
    return f"{_base(module)}/dnn/answer"
