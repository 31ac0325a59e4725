"""The scaling controller: ``reconcile_scaling(module, deps, now) -> Outcome`` for a shared
SoftwareModule with ``spec.scaling`` (backend ``fogfleet``).

One reconcile, level-based and restart-safe:

1. Read the metrics contract (``fogfleet.contract.metrics``) from Prometheus into a
   :class:`~fogfleet.autoscaling.policy.MetricsSnapshot`: the SLO per pool (contract histogram
   per ``tier``, or the raw ``slo.query``) for ``mode: reactive``; the offered rate of each
   privacy class for ``mode: predictive``; CPU utilisation (cAdvisor + kube-state-metrics) for
   a reactive module with ``targetCpuUtilizationPercent``. Ready replicas per pool come from
   the module's running pods (labels ``fogfleet.io/module`` and ``fogfleet.io/tier``).
2. :func:`fogfleet.autoscaling.policy.decide` with the spec's bounds, pools and behaviour
   (HPA semantics; ``preset: tinykube``). The memory it needs between runs -- the behaviour's
   recommendation and scale-event history and the previous rates -- lives in the annotation
   ``fogfleet.io/scaler-state``; the last decision itself is ``status.scaling``. A restarted
   operator therefore continues the same stabilisation windows.
3. Write ``status.scaling`` (desiredReplicas, pools per tier, reason, metricsAvailable,
   lastDecisionTime, lastScaleTime, observedSloMillis) and the conditions ``Scaling`` and
   ``MetricsUnavailable`` in one status patch; post ``ScaledUp``/``ScaledDown`` on a change,
   ``InvalidSLOQuery`` when Prometheus rejects the query, ``MetricsUnavailable`` when metrics
   go missing.

Prometheus unreachable, no data or a bad query: the decision is held (never below
``minReplicas``, never zero for a safety-relevant module), ``MetricsUnavailable=True`` says
why, nothing raises. The RobotFleet controller places ``status.scaling.pools`` (replica ``r``
of the module counted for the pool it belongs to, edge first) with the scheduler.

Blocking (Prometheus and API calls): run it in a worker thread.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fogfleet.api.labels import LABEL_MANAGED_BY, LABEL_MODULE, LABEL_TIER, MANAGER
from fogfleet.api.loader import parse_object
from fogfleet.api.names import label_value
from fogfleet.api.timestamps import parse_timestamp, timestamp
from fogfleet.api.v1alpha1.scaling import Mode, ScalingSpec
from fogfleet.api.v1alpha1.softwaremodule import SafetyClass, ScalingStatus, SoftwareModule
from fogfleet.autoscaling.behavior import (
    resolve_behavior,
)
from fogfleet.autoscaling.dispatch import plan_dispatch
from fogfleet.autoscaling.policy import (
    MetricsSnapshot,
    Policy,
    Pool,
    Predictive,
    ReactiveCpu,
    ReactiveSlo,
    ScaleDecision,
    TierMetrics,
    decide,
)
from fogfleet.autoscaling.pools import ALL, DISPATCH_RESERVE, pools_for
from fogfleet.autoscaling.state import ANNOTATION_STATE, dump_state, load_state
from fogfleet.controllers.deps import ScalingDeps, ScalingKube
from fogfleet.controllers.module.metrics import MetricsRead, read_metrics
from fogfleet.controllers.status import (
    condition,
    find_condition,
    pod_ready,
    scaling_status,
    set_conditions,
)
from fogfleet.snapshot.objects import written_status

__all__ = [
    "ANNOTATION_STATE",
    "Outcome",
    "ScalingDeps",
    "ScalingKube",
    "policy_for",
    "reconcile_scaling",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
COND_SCALING = "Scaling"
COND_METRICS = "MetricsUnavailable"


@dataclass(frozen=True)
class Outcome:
    replicas: Mapping[str, int] = field(default_factory=dict)
    total: int = 0
    changed: bool = False
    metrics_available: bool = True
    reason: str = ""
    problem: str = ""  # MetricsUnavailable reason, "" when metrics were read
    skipped: bool = False


# --------------------------------------------------------------------------- pure parts


def policy_for(spec: ScalingSpec, deps: ScalingDeps) -> Policy:
    if spec.mode is Mode.PREDICTIVE:
        return Predictive(
            period_seconds=deps.period_seconds,
            rate_window_seconds=float(deps.rate_window_seconds),
            reserve=DISPATCH_RESERVE,
        )
    if spec.slo is not None:
        return ReactiveSlo()
    return ReactiveCpu((spec.target_cpu_utilization_percent or 80) / 100.0)


def _parse_stamp(text: str | None) -> float:
    return parse_timestamp(text) or 0.0


def _current(
    module: SoftwareModule, pools: Sequence[Pool], scaling: ScalingStatus | None
) -> dict[str, int]:
    """Replicas per pool as last decided (status.scaling), or the starting point."""
    if scaling is not None:
        if pools and pools[0].name == ALL:
            return {ALL: scaling.desired_replicas}
        have = {p.tier: p.replicas for p in scaling.pools}
        return {p.name: have.get(p.name, p.min_replicas) for p in pools}
    out = {}
    for k, p in enumerate(pools):
        start = module.spec.replicas if k == 0 else p.min_replicas
        out[p.name] = min(max(start, p.min_replicas), p.max_replicas)
    return out


def _ready_by_pool(pods: Sequence[Obj], pools: Sequence[Pool]) -> dict[str, int]:
    out = {p.name: 0 for p in pools}
    for pod in pods:
        if not pod_ready(pod):
            continue
        tier = ((pod.get("metadata") or {}).get("labels") or {}).get(LABEL_TIER, "")
        name = ALL if ALL in out else tier
        if name in out:
            out[name] += 1
    return out


# --------------------------------------------------------------------------- reconcile


def _summary(pools: Sequence[Pool], before: Mapping[str, int], after: Mapping[str, int]) -> str:
    parts = [f"{p.name} {before.get(p.name, 0)} -> {after[p.name]}" for p in pools]
    return ", ".join(parts)


def _admission_forecast(
    private_rate: float | None,
    normal_rate: float | None,
    pools: Sequence[Pool],
    replicas: Mapping[str, int],
) -> Obj:
    """tinyKube III-B: the share of each traffic class the decided pools would reject, from
    the queueing model and the dispatcher (privacy-constrained traffic only on pools that
    accept it). Empty when the offered load is unknown."""
    if private_rate is None or normal_rate is None:
        return {}
    plan = plan_dispatch(
        private_rate,
        normal_rate,
        [p.tier for p in pools],
        [replicas[p.name] for p in pools],
        [p.target_seconds for p in pools],
        DISPATCH_RESERVE,
    )
    return {
        "predictedPrivateRejected": round(plan.private_rejected / private_rate, 6)
        if private_rate > 0
        else 0.0,
        "predictedNormalRejected": round(plan.normal_rejected / normal_rate, 6)
        if normal_rate > 0
        else 0.0,
    }


def reconcile_scaling(module: Mapping[str, Any], deps: ScalingDeps, now: float) -> Outcome:
    """One scaling decision for ``module`` (the SoftwareModule as the API server sends it)."""
    meta = module.get("metadata") or {}
    ns, name = meta.get("namespace") or "default", meta["name"]
    body = {k: v for k, v in module.items() if k != "status"}
    mod = parse_object(body)
    if not isinstance(mod, SoftwareModule) or mod.spec.scaling is None:
        return Outcome(skipped=True, reason="no spec.scaling")
    spec = mod.spec.scaling
    if spec.backend.value != "fogfleet":
        return Outcome(skipped=True, reason=f"backend {spec.backend.value} scales this module")
    status = written_status(module)
    old = scaling_status(module)
    pools = pools_for(mod)
    safety = mod.spec.taxonomy.safety is SafetyClass.RELEVANT
    current = _current(mod, pools, old)
    pods = deps.kube.list_pods(ns, {LABEL_MODULE: label_value(name), LABEL_MANAGED_BY: MANAGER})
    ready = _ready_by_pool(pods, pools)
    last = (
        ScaleDecision(
            _parse_stamp(old.last_decision_time),
            dict(current),
            old.reason,
            not old.metrics_available,
        )
        if old is not None
        else None
    )
    state = load_state((meta.get("annotations") or {}).get(ANNOTATION_STATE), last)

    read = read_metrics(mod, spec, pools, current, ready, pods, deps)
    snapshot = MetricsSnapshot(
        now,
        tuple(read.tiers[p.name] for p in pools),
        read.private_rate,
        read.normal_rate,
    )
    if read.problem:  # make sure the policy sees missing metrics whatever it reads
        snapshot = MetricsSnapshot(
            now, tuple(TierMetrics(t.name, t.replicas, t.ready_replicas) for t in snapshot.tiers)
        )
    decision, new_state = decide(
        policy_for(spec, deps),
        snapshot,
        pools,
        state,
        behavior=resolve_behavior(spec),
        safety_relevant=safety,
    )
    replicas = {p.name: int(decision.replicas[p.name]) for p in pools}
    before_total, total = sum(current.values()), sum(replicas.values())
    changed = replicas != current
    reason = decision.reason
    if read.problem:
        reason = f"{reason} ({read.problem}: {read.message})"
    gen = meta.get("generation")
    if read.problem:
        conds = [
            condition(
                COND_SCALING, False, read.problem, f"Holding {total} replicas: {read.message}", gen
            ),
            condition(COND_METRICS, True, read.problem, read.message, gen),
        ]
    else:
        verb = (
            "ScaledUp"
            if total > before_total
            else "ScaledDown"
            if total < before_total
            else ("Rebalanced" if changed else "Stable")
        )
        conds = [
            condition(
                COND_SCALING, True, verb, f"{_summary(pools, current, replicas)}: {reason}", gen
            ),
            condition(COND_METRICS, False, "MetricsRead", "Prometheus answered every query", gen),
        ]
    merged = set_conditions(status.get("conditions"), conds)  # keeps the others' conditions
    slo_millis = (
        None
        if read.slo_seconds is None or not math.isfinite(read.slo_seconds)
        else round(read.slo_seconds * 1e3, 3)
    )
    new_scaling: Obj = {
        "desiredReplicas": total,
        "pools": [
            {"tier": p.name, "replicas": replicas[p.name], "ready": ready[p.name]}
            for p in pools
            if p.name != ALL
        ],
        "reason": reason[:1000],
        "metricsAvailable": not read.problem,
        "lastDecisionTime": timestamp(now),
        "lastScaleTime": timestamp(now) if changed else (old.last_scale_time if old else None),
        "observedSloMillis": slo_millis,
        **_admission_forecast(read.private_rate, read.normal_rate, pools, replicas),
    }
    deps.kube.patch_module_status(ns, name, {"scaling": new_scaling, "conditions": merged})
    if not read.problem:
        deps.kube.patch_module_annotations(ns, name, {ANNOTATION_STATE: dump_state(new_state)})
    was = find_condition(status.get("conditions"), COND_METRICS)
    _events(module, deps, was, read, pools, current, replicas, before_total, total, reason)
    if changed:
        log.info("Scaled SoftwareModule %s/%s: %s (%s)", ns, name,
                 _summary(pools, current, replicas), reason)  # fmt: skip
    return Outcome(replicas, total, changed, not read.problem, reason, read.problem)


def _events(
    module: Mapping[str, Any],
    deps: ScalingDeps,
    metrics_before: Mapping[str, Any] | None,
    read: MetricsRead,
    pools: Sequence[Pool],
    current: Mapping[str, int],
    replicas: Mapping[str, int],
    before_total: int,
    total: int,
    reason: str,
) -> None:
    before = metrics_before or {}
    if read.problem:
        repeated = (
            before.get("status") == "True"
            and before.get("reason") == read.problem
            and before.get("message") == read.message[:2000]
        )
        if not repeated:
            kind = "InvalidSLOQuery" if read.problem == "InvalidSLOQuery" else COND_METRICS
            deps.kube.emit_event(
                module, "Warning", kind, f"{read.message}; holding {total} replicas"
            )
    if replicas != dict(current):
        kind = (
            "ScaledUp"
            if total > before_total
            else "ScaledDown"
            if total < before_total
            else ("Rebalanced")
        )
        deps.kube.emit_event(
            module, "Normal", kind, f"{_summary(pools, current, replicas)}: {reason}"
        )
