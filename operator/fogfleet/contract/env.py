"""The environment the operator renders into a module's containers and the workload reads.

``render.ros.module_env`` writes these; ``workload.spec.WorkloadSpec.from_env`` reads them
(``render.profiling`` and ``workload.profile`` share the profiling pair). A name changed here
changes on both sides at once.

=============================  ===============================================================
variable                       value
=============================  ===============================================================
FOGFLEET_MODULE_SPEC           the SoftwareModule as JSON (topics, cycle, activation, profile
                               rows)
FOGFLEET_FLEET                 the RobotFleet's name
FOGFLEET_ROBOT                 the robot the instance serves ("" for a shared module)
FOGFLEET_MODULE                the module's name (a variant's standby: the module it stands in
                               for)
FOGFLEET_VARIANT               a variant's standby only: the variant's own name
FOGFLEET_TIER                  ``robot``, ``edge`` or ``cloud``
FOGFLEET_NODE                  the node (the downward API's spec.nodeName for a plain
                               Deployment)
FOGFLEET_HARDWARE_TYPE         the node's hardware type (absent for a plain Deployment)
FOGFLEET_CPU                   the CPU limit as a quantity (absent: no limit)
FOGFLEET_ROLE                  ``primary`` (default), ``remote`` or ``standby`` (on-board
                               fallback); a split DNN module's ``head`` or ``tail``
                               (``contract.dnn``)
FOGFLEET_PROFILE_CYCLES        a profiling Job: run this many cycles alone, then exit
FOGFLEET_PROFILE_OUTPUT        where the profiling run writes its rows (default /tmp)
FOGFLEET_METRICS_HOST          the workload's own: its metrics address (default 0.0.0.0)
FOGFLEET_METRICS_PORT          the workload's own: its metrics port (default ``METRICS_PORT``)
FOGFLEET_DNN_MODELS            the workload's own: a split DNN module's model folder (default:
                               where the image's build stage wrote them)
FOGFLEET_LOG_INTERVAL_SECONDS  the workload's own: seconds between its log lines of cycles,
                               misses and messages (default ``LOG_INTERVAL_SECONDS``; 0: none)
=============================  ===============================================================
"""

from __future__ import annotations

__all__ = [
    "ENV_CPU",
    "ENV_DNN_MODELS",
    "ENV_FLEET",
    "ENV_HARDWARE_TYPE",
    "ENV_LOG_INTERVAL",
    "ENV_METRICS_HOST",
    "ENV_METRICS_PORT",
    "ENV_MODULE",
    "ENV_MODULE_SPEC",
    "ENV_NODE",
    "ENV_PROFILE_CYCLES",
    "ENV_PROFILE_OUTPUT",
    "ENV_ROBOT",
    "ENV_ROLE",
    "ENV_TIER",
    "ENV_VARIANT",
    "LOG_INTERVAL_SECONDS",
    "METRICS_PORT",
]

ENV_MODULE_SPEC = "FOGFLEET_MODULE_SPEC"
ENV_FLEET = "FOGFLEET_FLEET"
ENV_ROBOT = "FOGFLEET_ROBOT"
ENV_MODULE = "FOGFLEET_MODULE"
ENV_VARIANT = "FOGFLEET_VARIANT"
ENV_TIER = "FOGFLEET_TIER"
ENV_NODE = "FOGFLEET_NODE"
ENV_HARDWARE_TYPE = "FOGFLEET_HARDWARE_TYPE"
ENV_CPU = "FOGFLEET_CPU"
ENV_ROLE = "FOGFLEET_ROLE"
ENV_PROFILE_CYCLES = "FOGFLEET_PROFILE_CYCLES"
ENV_PROFILE_OUTPUT = "FOGFLEET_PROFILE_OUTPUT"
ENV_METRICS_HOST = "FOGFLEET_METRICS_HOST"
ENV_METRICS_PORT = "FOGFLEET_METRICS_PORT"
ENV_LOG_INTERVAL = "FOGFLEET_LOG_INTERVAL_SECONDS"
ENV_DNN_MODELS = "FOGFLEET_DNN_MODELS"

METRICS_PORT = 9100  # the metrics contract and /healthz, in every module container
LOG_INTERVAL_SECONDS = 10.0  # a module's sign of life in `kubectl logs`
