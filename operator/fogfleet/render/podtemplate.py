"""A module's pod spec: the user's pod-template subset merged with what fogfleet owns.

fogfleet owns the placement (node affinity), the module container's CPU (from the plan) and
memory (spec.resources), the labels, the ROS 2 wiring's environment and a writable ``/tmp``;
the user owns the rest of ``spec.template``. Where the template says nothing the pod gets the
restricted Pod Security Standard: non-root, no privilege escalation, every capability dropped,
seccomp RuntimeDefault, read-only root filesystem, no ServiceAccount token.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from fogfleet.api.v1alpha1.base import FogModel
from fogfleet.api.v1alpha1.podtemplate import ContainerBase, Probe, SecurityContext, Sidecar
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.api.v1alpha1.template import ContainerTemplate
from fogfleet.render.ros import PLANNED_TOLERATION, pod_security

__all__ = ["TMP_VOLUME", "module_pod_spec", "scrape_port"]

Obj = dict[str, Any]
TMP_VOLUME = {"name": "tmp", "emptyDir": {"sizeLimit": "64Mi"}}
_TMP_MOUNT = {"name": "tmp", "mountPath": "/tmp"}


def _env(env: Sequence[FogModel], owned_env: Sequence[Mapping[str, Any]]) -> list[Obj]:
    out = []
    for e in env:
        wire = e.wire()
        if "valueFrom" in wire and not wire.get("value"):
            del wire["value"]
        out.append(wire)
    return out + [dict(e) for e in owned_env]


def scrape_port(tpl: ContainerTemplate) -> int | None:
    """The port Prometheus scrapes: the module's metricsPort, else its first sidecar's (the
    cycle-time probe of a module nobody instrumented)."""
    ports = [tpl.metrics_port] + [c.metrics_port for c in tpl.sidecars]
    return next((p for p in ports if p), None)


def _security(sc: SecurityContext | None) -> Obj:
    _, out = pod_security()
    if sc is None:
        return out
    if sc.run_as_user is not None:
        out["runAsUser"] = sc.run_as_user
    if sc.run_as_group is not None:
        out["runAsGroup"] = sc.run_as_group
    if sc.run_as_non_root is not None:
        out["runAsNonRoot"] = sc.run_as_non_root
    if sc.read_only_root_filesystem is not None:
        out["readOnlyRootFilesystem"] = sc.read_only_root_filesystem
    if sc.privileged:
        out["privileged"] = True
        out["allowPrivilegeEscalation"] = True  # the API server refuses privileged without it
    if sc.capabilities and sc.capabilities.add:
        out["capabilities"] = {"drop": ["ALL"], "add": list(sc.capabilities.add)}
    return out


def _health_probes(port_name: str) -> Obj:
    probe = {"httpGet": {"path": "/healthz", "port": port_name}, "periodSeconds": 10}
    return {
        "livenessProbe": {**probe, "initialDelaySeconds": 10, "failureThreshold": 6},
        "readinessProbe": {**probe, "initialDelaySeconds": 2},
    }


def _probes(tpl: ContainerTemplate) -> Obj:
    """The probes the user set, over the /healthz ones ``_container`` added."""
    out: Obj = {}
    mine: dict[str, Probe | None] = {
        "livenessProbe": tpl.liveness_probe,
        "readinessProbe": tpl.readiness_probe,
        "startupProbe": tpl.startup_probe,
    }
    out.update({key: p.wire() for key, p in mine.items() if p is not None})
    return out


def _container(
    spec: ContainerBase,
    name: str,
    metrics_port_name: str,
    sc: SecurityContext | None,
    mounts: Sequence[FogModel],
    owned_env: Sequence[Mapping[str, Any]],
) -> Obj:
    """What the module's container and a sidecar render alike: image, entry point, env (the
    user's, then fogfleet's wiring), security context, /tmp and the other mounts, ports (the
    metrics port first, named ``metrics_port_name``) and its /healthz probes."""
    out: Obj = {"name": name, "image": spec.image}
    if spec.image_pull_policy:
        out["imagePullPolicy"] = spec.image_pull_policy
    if spec.command:
        out["command"] = list(spec.command)
    if spec.args:
        out["args"] = list(spec.args)
    env = _env(spec.env, owned_env)
    if env:
        out["env"] = env
    out["securityContext"] = _security(sc)
    out["volumeMounts"] = [_TMP_MOUNT, *(m.wire() for m in mounts)]
    ports = [p.wire() for p in spec.ports]
    if spec.metrics_port:
        port = {"name": metrics_port_name, "containerPort": spec.metrics_port, "protocol": "TCP"}
        ports.insert(0, port)
        out.update(_health_probes(metrics_port_name))
    if ports:
        out["ports"] = ports
    return out


def _module_container(
    tpl: ContainerTemplate, name: str, resources: Obj, owned_env: Sequence[Mapping[str, Any]]
) -> Obj:
    out = _container(tpl, name, "metrics", tpl.security_context, tpl.volume_mounts, owned_env)
    if tpl.env_from:
        out["envFrom"] = [e.wire() for e in tpl.env_from]
    extra = {k: str(v) for k, v in tpl.extra_resources.items()}
    limits = {**resources.get("limits", {}), **extra}
    requests = {**resources["requests"], **extra}
    out["resources"] = {"requests": requests, **({"limits": limits} if limits else {})}
    out.update(_probes(tpl))
    return out


def _sidecar(car: Sidecar, tpl: ContainerTemplate, owned_env: Sequence[Mapping[str, Any]]) -> Obj:
    port_name = f"m-{car.name}"[:15].rstrip("-")
    out = _container(car, car.name, port_name, tpl.security_context, car.volume_mounts, owned_env)
    quantities = {"cpu": str(car.cpu), "memory": str(car.memory)}
    out["resources"] = {"requests": dict(quantities), "limits": dict(quantities)}
    return out


def module_pod_spec(
    module: SoftwareModule,
    *,
    container_name: str,
    affinity: Obj,
    resources: Obj,
    owned_env: Sequence[Mapping[str, Any]],
) -> Obj:
    """The pod spec of one instance of ``module``: containers, volumes and pod settings."""
    tpl = module.spec.template
    pod_sc, _ = pod_security()
    sc = tpl.security_context
    if sc is not None:
        if sc.run_as_non_root is False:
            pod_sc["runAsNonRoot"] = False
        if sc.supplemental_groups:
            pod_sc["supplementalGroups"] = list(sc.supplemental_groups)
    spec: Obj = {
        "affinity": affinity,
        "automountServiceAccountToken": tpl.automount_service_account_token,
        "securityContext": pod_sc,
        "containers": [
            _module_container(tpl, container_name, resources, owned_env),
            *(_sidecar(car, tpl, owned_env) for car in tpl.sidecars),
        ],
        "enableServiceLinks": False,
        "volumes": [dict(TMP_VOLUME), *(v.wire() for v in tpl.volumes)],
    }
    if tpl.service_account_name:
        spec["serviceAccountName"] = tpl.service_account_name
    if tpl.image_pull_secrets:
        spec["imagePullSecrets"] = [r.wire() for r in tpl.image_pull_secrets]
    own = [t.wire() for t in tpl.tolerations]
    spec["tolerations"] = own + ([] if PLANNED_TOLERATION in own else [dict(PLANNED_TOLERATION)])
    return spec
