"""Render ``spec.scaling`` as an HPA or a KEDA ScaledObject (``backend: hpa | keda``), for teams
that already run them (pure: dicts in, dicts out).

Both get the same ``behavior`` block fogfleet's own scaler applies (HPA semantics; the tinyKube
preset resolved), the module's bounds, and the SLO as a ``Value`` target, so the replica formula
is ``ceil(replicas * measured / target)`` -- fogfleet's ``reactive`` mode on the SLO:

* **KEDA**: a ``prometheus`` trigger with the contract query (or ``slo.query``), ``metricType:
  Value``, ``threshold`` = the target in seconds.
* **HPA** (``autoscaling/v2``): with ``targetCpuUtilizationPercent`` a ``Resource`` metric; with
  an SLO an ``External`` metric ``fogfleet_slo_seconds{module=...}`` that a Prometheus adapter
  must serve (its rule: the contract query), target ``Value``.

They scale one workload (``target``: a Deployment name). Pools per tier and the predictive mode
need fogfleet's own backend (the API rejects ``predictive`` with another backend).

:func:`module_hpas` picks that workload in a rendered fleet. Each replica of a shared module is
a Deployment of its own, pinned to the node the plan chose, and an HPA scales one Deployment:
it gets the module's first placed replica, and the bounds of the whole module less the other
planned replicas (which stay where the plan put them), so the module keeps between
``minReplicas`` and ``maxReplicas`` in total. The operator applies neither object: it plans
every replica onto a node and re-applies what it planned, which an in-cluster HPA would fight.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fogfleet.api.labels import (
    ANNOTATION_MODULE,
    ANNOTATION_REPLICA,
    ANNOTATION_ROBOT,
    ANNOTATION_ROLE,
    LABEL_MANAGED_BY,
    LABEL_MODULE,
    MANAGER,
)
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.scaling import Backend, ScalingSpec
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.autoscaling.behavior import Behavior, ScalingRules, resolve_behavior
from fogfleet.contract import metrics as contract
from fogfleet.render.names import hpa_name, scaled_object_name

__all__ = [
    "SLO_METRIC",
    "ModuleHpa",
    "behavior_block",
    "module_hpas",
    "render_hpa",
    "render_scaled_object",
    "slo_promql",
]

SLO_METRIC = "fogfleet_slo_seconds"
Obj = dict[str, Any]


def _rules(rules: ScalingRules) -> Obj:
    return {
        "stabilizationWindowSeconds": rules.stabilization_window_seconds,
        "selectPolicy": rules.select_policy.value,
        "policies": [
            {"type": p.type.value, "value": p.value, "periodSeconds": p.period_seconds}
            for p in rules.policies
        ],
    }


def behavior_block(behavior: Behavior) -> Obj:
    """An HPA ``spec.behavior`` with every field explicit."""
    return {"scaleUp": _rules(behavior.scale_up), "scaleDown": _rules(behavior.scale_down)}


def slo_promql(spec: ScalingSpec, module: str, namespace: str, window_seconds: int = 60) -> str:
    if spec.slo is None:
        raise ValueError("the module's scaling has no slo")
    if spec.slo.query:
        return spec.slo.query
    assert spec.slo.metric is not None
    return contract.slo_query(
        spec.slo.metric,
        module=module,
        namespace=namespace,
        percentile=spec.slo.percentile,
        window_seconds=window_seconds,
    )


def _meta(name: str, module: str, namespace: str) -> Obj:
    return {
        "name": name,
        "namespace": namespace,
        "labels": {LABEL_MANAGED_BY: MANAGER, LABEL_MODULE: label_value(module)},
    }


def render_scaled_object(
    spec: ScalingSpec,
    *,
    fleet: str,
    module: str,
    namespace: str,
    target: str,
    prometheus_url: str,
    polling_seconds: int = 15,
) -> Obj:
    """A KEDA ``ScaledObject`` scaling Deployment ``target`` (the replica of ``module`` in
    ``fleet``) on the SLO (or CPU)."""
    if spec.slo is not None:
        trigger: Obj = {
            "type": "prometheus",
            "metricType": "Value",
            "metadata": {
                "serverAddress": prometheus_url,
                "query": slo_promql(spec, module, namespace),
                "threshold": f"{spec.slo.target_millis / 1000:g}",
            },
        }
    else:
        trigger = {
            "type": "cpu",
            "metricType": "Utilization",
            "metadata": {"value": str(spec.target_cpu_utilization_percent or 80)},
        }
    return {
        "apiVersion": "keda.sh/v1alpha1",
        "kind": "ScaledObject",
        "metadata": _meta(scaled_object_name(fleet, module), module, namespace),
        "spec": {
            "scaleTargetRef": {"apiVersion": "apps/v1", "kind": "Deployment", "name": target},
            "minReplicaCount": spec.min_replicas,
            "maxReplicaCount": spec.max_replicas,
            "pollingInterval": polling_seconds,
            "advanced": {
                "horizontalPodAutoscalerConfig": {
                    "behavior": behavior_block(resolve_behavior(spec))
                }
            },
            "triggers": [trigger],
        },
    }


def render_hpa(spec: ScalingSpec, *, fleet: str, module: str, namespace: str, target: str) -> Obj:
    """An ``autoscaling/v2`` HorizontalPodAutoscaler for Deployment ``target`` (the replica of
    ``module`` in ``fleet``)."""
    if spec.slo is not None:
        metric: Obj = {
            "type": "External",
            "external": {
                "metric": {
                    "name": SLO_METRIC,
                    "selector": {"matchLabels": {"module": module, "namespace": namespace}},
                },
                "target": {"type": "Value", "value": f"{spec.slo.target_millis}m"},
            },
        }
    else:
        metric = {
            "type": "Resource",
            "resource": {
                "name": "cpu",
                "target": {
                    "type": "Utilization",
                    "averageUtilization": spec.target_cpu_utilization_percent or 80,
                },
            },
        }
    return {
        "apiVersion": "autoscaling/v2",
        "kind": "HorizontalPodAutoscaler",
        "metadata": _meta(hpa_name(fleet, module), module, namespace),
        "spec": {
            "scaleTargetRef": {"apiVersion": "apps/v1", "kind": "Deployment", "name": target},
            "minReplicas": max(spec.min_replicas, 1),  # the HPA's own floor
            "maxReplicas": spec.max_replicas,
            "metrics": [metric],
            "behavior": behavior_block(resolve_behavior(spec)),
        },
    }


@dataclass(frozen=True)
class ModuleHpa:
    """The HPA of one shared module with ``backend: hpa``, and what it scales."""

    module: str
    hpa: Obj
    target: str
    """The Deployment it scales (its first placed replica)."""
    fixed: int
    """The module's other planned replicas, which the HPA leaves alone."""


def _shared_replica(deployment: Mapping[str, Any]) -> tuple[str, int] | None:
    """(module, replica) of a shared module's replica Deployment, else None."""
    ann = (deployment.get("metadata") or {}).get("annotations") or {}
    if ANNOTATION_MODULE not in ann or ann.get(ANNOTATION_ROBOT) or ann.get(ANNOTATION_ROLE):
        return None
    return ann[ANNOTATION_MODULE], int(ann.get(ANNOTATION_REPLICA, "0"))


def module_hpas(
    deployments: Sequence[Mapping[str, Any]],
    modules: Mapping[str, SoftwareModule],
    namespace: str,
    fleet: str,
) -> list[ModuleHpa]:
    """An HPA for every shared module of ``modules`` with ``scaling.backend: hpa`` that has a
    placed replica among ``deployments`` (``fleet``'s rendered Deployments), in module order."""
    replicas: dict[str, list[tuple[int, str]]] = {}
    for dep in deployments:
        ident = _shared_replica(dep)
        if ident is not None:
            replicas.setdefault(ident[0], []).append((ident[1], dep["metadata"]["name"]))
    out: list[ModuleHpa] = []
    for name in sorted(replicas):
        module = modules.get(name)
        spec = module.spec.scaling if module is not None else None
        if spec is None or spec.backend is not Backend.HPA:
            continue
        placed = sorted(replicas[name])
        fixed = len(placed) - 1
        low = max(spec.min_replicas - fixed, 1)  # the HPA's own floor is 1
        bounds = {"min_replicas": low, "max_replicas": max(spec.max_replicas - fixed, low)}
        target = placed[0][1]
        hpa = render_hpa(
            spec.model_copy(update=bounds),
            fleet=fleet,
            module=name,
            namespace=namespace,
            target=target,
        )
        out.append(ModuleHpa(name, hpa, target, fixed))
    return out
