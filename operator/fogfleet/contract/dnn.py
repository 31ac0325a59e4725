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

**Profiling** (``SoftwareModule.spec.profiling.mode: auto`` beside ``spec.dnn``): the operator's
profiling Job runs the same image with ``FOGFLEET_PROFILE_CYCLES=N`` (``contract.env``) and, in
``FOGFLEET_MODULE_SPEC``, ``PROFILE_KEY`` instead of ``SPEC_KEY``: ``{"splitPoints": [names, in
order]}``. The workload then times every part of the image's network on its node (the whole
network, the local model, every split point's head and tail; one thread, the thread's CPU time,
the median of N frames after ``PROFILE_WARMUP`` untimed ones) and writes one JSON line to its
termination message: ``cycles`` (N), ``meanMillis`` / ``stdMillis`` (the whole network's, as
every profiling Job reports), ``cpuSeconds``, ``wallSeconds`` and, under ``RESULT_KEY``,
``{"inputBytes", "outputBytes", "fullMillis", "localMillis", "splitPoints": [{"name",
"headMillis", "tailMillis", "tensorBytes"}, ...]}`` (milliseconds, bytes per frame).
"""

from __future__ import annotations

__all__ = [
    "FULL_OFFLOAD",
    "KEY_PLANNED_ACTION",
    "KEY_ROBOT_FACTOR",
    "KEY_TAIL_FACTOR",
    "PROFILE_KEY",
    "PROFILE_WARMUP",
    "RESULT_KEY",
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
PROFILE_KEY = "dnnProfile"  # a profiling Job's module spec: what to time (see above)
RESULT_KEY = "dnn"  # its result line: what it timed
PROFILE_WARMUP = 3  # untimed frames per part before the timed ones


def _base(module: str) -> str:
    """A ROS 2 name from a module's (Kubernetes names may hold dashes; ROS names may not)."""
    return module.replace("-", "_").strip("/")


def tensor_topic(module: str) -> str:
    """Head -> tail: a frame's tensor (or the raw frame for full offload), and probes."""
    return f"{_base(module)}/dnn/tensor"


def answer_topic(module: str) -> str:
    """Tail -> head: a frame's answer, and the probes' echoes."""
    return f"{_base(module)}/dnn/answer"
