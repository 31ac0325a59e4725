"""The profiling Job of a module on one hardware type at one CPU limit (issue 10).

The module's own container (its image, command, args, env and security context, as its
Deployments run it) in a Job pinned to the nodes of that hardware type, with the CPU limit
both requested and enforced, ``FOGFLEET_PROFILE_CYCLES`` set (the profiling contract:
``api.v1alpha1.profiling``) and nothing that belongs to a long-running pod: no sidecars (a Job
ends when all its containers do), no probes, no ports. The Job is owned by its
SoftwareModule, so deleting the module deletes its profiling. A split network's Job
(``spec.dnn``) is told the split points to time (``contract.dnn.PROFILE_KEY``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fogfleet import API_VERSION
from fogfleet.api.labels import (
    COMPONENT_PROFILING,
    LABEL_COMPONENT,
    LABEL_MANAGED_BY,
    LABEL_MODULE,
    LABEL_PROFILE_CPU,
    LABEL_PROFILE_HARDWARE,
    LABEL_PROFILE_SPEC,
    MANAGER,
)
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.base import format_millicores
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.contract.env import ENV_PROFILE_CYCLES
from fogfleet.render.deployments import node_affinity
from fogfleet.render.names import container_name, profiling_job_name
from fogfleet.render.podtemplate import module_pod_spec
from fogfleet.render.ros import module_env, stay_on_robot

__all__ = ["ENV_PROFILE_CYCLES", "profiling_selector", "render_profiling_job"]

TTL_SECONDS = 3600  # the operator deletes a recorded run's Jobs; this cleans up the rest


def profiling_selector(module: str, hardware_type: str, spec_hash: str) -> dict[str, str]:
    """The labels of one module's profiling Jobs on one hardware type, for one spec."""
    return {
        LABEL_COMPONENT: COMPONENT_PROFILING,
        LABEL_MODULE: label_value(module),
        LABEL_PROFILE_HARDWARE: label_value(hardware_type),
        LABEL_PROFILE_SPEC: spec_hash,
    }


def render_profiling_job(
    module: SoftwareModule,
    *,
    hardware_type: str,
    cpu: float,
    node_names: Sequence[str],
    robots: bool,
    spec_hash: str,
) -> dict[str, Any]:
    """The Job that measures ``module`` on ``node_names`` (all of ``hardware_type``; ``robots``
    when they are robots) with ``cpu`` cores."""
    assert module.spec.profiling is not None
    name = module.metadata.name
    limit = format_millicores(cpu)
    memory = str(module.spec.resources.memory)
    quantities = {"cpu": limit, "memory": memory}
    dnn = module.spec.dnn
    env = module_env(
        None,
        fleet="",
        robot="",
        module=module,
        tier="",
        node="",
        hardware_type=hardware_type,
        cpu=limit,
        dnn_profile=None if dnn is None else [p.name for p in dnn.split_points],
    )
    for var in env:
        if var["name"] == "FOGFLEET_NODE":  # wherever kube-scheduler puts it
            del var["value"]
            var["valueFrom"] = {"fieldRef": {"apiVersion": "v1", "fieldPath": "spec.nodeName"}}
    env.append({"name": ENV_PROFILE_CYCLES, "value": str(module.spec.profiling.cycles)})
    pod = module_pod_spec(
        module,
        container_name=container_name(name),
        affinity=node_affinity(node_names),
        resources={"requests": dict(quantities), "limits": dict(quantities)},
        owned_env=env,
    )
    container = pod["containers"][0]
    for key in ("livenessProbe", "readinessProbe", "startupProbe", "ports"):
        container.pop(key, None)
    container["terminationMessagePolicy"] = "File"  # the result is the termination message
    pod["containers"] = [container]
    pod["restartPolicy"] = "Never"
    if robots:
        stay_on_robot(pod)
    labels = {
        **profiling_selector(name, hardware_type, spec_hash),
        LABEL_MANAGED_BY: MANAGER,
        LABEL_PROFILE_CPU: limit,
    }
    metadata: dict[str, Any] = {
        "name": profiling_job_name(name, hardware_type, cpu, spec_hash),
        "namespace": module.metadata.namespace or "default",
        "labels": labels,
    }
    if module.metadata.uid:
        metadata["ownerReferences"] = [
            {
                "apiVersion": API_VERSION,
                "kind": "SoftwareModule",
                "name": name,
                "uid": module.metadata.uid,
            }
        ]
    pod_labels = {k: v for k, v in labels.items() if k != LABEL_MANAGED_BY}
    return {
        "apiVersion": "batch/v1",
        "kind": "Job",
        "metadata": metadata,
        "spec": {
            "backoffLimit": 1,
            "activeDeadlineSeconds": module.spec.profiling.timeout_seconds,
            "ttlSecondsAfterFinished": TTL_SECONDS,
            "template": {"metadata": {"labels": pod_labels}, "spec": pod},
        },
    }
