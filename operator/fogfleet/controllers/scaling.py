"""The scaling controller: ``reconcile_scaling(module, deps, now) -> Outcome`` for a shared
SoftwareModule with ``spec.scaling`` (backend ``fogfleet``).

One reconcile, level-based and restart-safe:

1. Read the metrics contract (``fogfleet.autoscaling.contract``) from Prometheus into a
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

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Protocol

from fogfleet.adapters.prometheus import QUERY_FIELD, PrometheusPort
from fogfleet.api.loader import parse_object
from fogfleet.api.v1alpha1.base import parse_quantity
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.scaling import Mode, ScalingSpec, TierName
from fogfleet.api.v1alpha1.softwaremodule import SafetyClass, SoftwareModule
from fogfleet.autoscaling import contract
from fogfleet.autoscaling.behavior import BehaviorState, Recommendation, ScaleEvent
from fogfleet.autoscaling.dispatch import plan_dispatch
from fogfleet.autoscaling.policy import (
    MetricsSnapshot,
    Policy,
    Pool,
    Predictive,
    ReactiveCpu,
    ReactiveSlo,
    ScaleDecision,
    ScalerState,
    TierMetrics,
    decide,
)
from fogfleet.domain.network import DEFAULT_UPLINK, path
from fogfleet.errors import DependencyUnavailable, InvalidSpec
from fogfleet.render.deployments import LABEL_MANAGED_BY, LABEL_MODULE, LABEL_TIER, MANAGER

from .status import condition, merge_conditions

__all__ = [
    "ANNOTATION_STATE",
    "DISPATCH_RESERVE",
    "Outcome",
    "ScalingDeps",
    "ScalingKube",
    "dump_state",
    "load_state",
    "policy_for",
    "pools_for",
    "reconcile_scaling",
    "service_rate",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
ANNOTATION_STATE = "fogfleet.io/scaler-state"
DISPATCH_RESERVE = 2  # edge places kept for private requests (the bench's and the twin's)
ALL = "all"  # the single pool of a module without spec.scaling.pools
COND_SCALING = "Scaling"
COND_METRICS = "MetricsUnavailable"
_TIER_ORDER = {TierName.EDGE: 0, TierName.CLOUD: 1}


class ScalingKube(Protocol):
    """What the scaling controller needs from the API server (blocking calls)."""

    def list_pods(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...

    def patch_module_status(self, namespace: str, name: str, status: Mapping[str, Any]) -> None:
        """One JSON merge patch of the SoftwareModule's status subresource."""
        ...

    def patch_module_annotations(
        self, namespace: str, name: str, annotations: Mapping[str, str | None]
    ) -> None: ...

    def emit_event(
        self, involved: Mapping[str, Any], type_: str, reason: str, message: str
    ) -> None: ...


@dataclass
class ScalingDeps:
    kube: ScalingKube
    prometheus: PrometheusPort
    period_seconds: float = 15.0  # how often the timer decides (the HPA's sync period)
    slo_window_seconds: int = 60  # rate() window of the SLO histogram
    rate_window_seconds: int = 10  # rate() window of the offered load (predictive)
    cpu_window_seconds: int = 60


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


def service_rate(module: SoftwareModule) -> float:
    """Requests/s one replica completes (mu): 1 / mean execution time of the profile.

    The ``default`` hardware row if there is one, else the median row: a pool spans several
    hardware types, and the median is robust to one very fast or very slow machine."""
    rows = [r for r in module.spec.profile if r.hardware_type == "default"] or list(
        module.spec.profile
    )
    means = sorted(parse_quantity(r.mean_millis) / 1e3 for r in rows)
    return 1.0 / means[len(means) // 2]


def _round_trip(tier: Tier) -> float:
    """Robot -> tier -> robot network time with the default uplinks (domain/network.py)."""
    return 2.0 * path(DEFAULT_UPLINK[Tier.ROBOT], DEFAULT_UPLINK[tier]).latency


def pools_for(module: SoftwareModule) -> list[Pool]:
    """The policy's pools from ``spec.scaling`` (edge before cloud), or one pool ``all``."""
    spec = module.spec.scaling
    if spec is None:
        return []
    mu = service_rate(module)
    pct = (spec.slo.percentile if spec.slo else 95) / 100.0
    # without an SLO (CPU scaling) the module's cycle time is the response-time target
    target = (
        spec.slo.target_millis / 1e3
        if spec.slo
        else parse_quantity(module.spec.cycle_time_millis) / 1e3
    )
    setup = (spec.setup_millis or 0) / 1e3
    if not spec.pools:
        return [Pool(ALL, spec.min_replicas, spec.max_replicas, mu, target, pct, setup, 0.0, True)]
    out = []
    for p in sorted(spec.pools, key=lambda p: _TIER_ORDER[p.tier]):
        out.append(
            Pool(
                p.tier.value,
                spec.min_replicas if p.min_replicas is None else p.min_replicas,
                p.max_replicas,
                mu,
                p.slo_target_millis / 1e3 if p.slo_target_millis else target,
                pct,
                (p.setup_millis / 1e3) if p.setup_millis is not None else setup,
                _round_trip(Tier(p.tier.value)),
                p.private_allowed,
            )
        )
    return out


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


def dump_state(state: ScalerState) -> str:
    """The behaviour memory and the previous rates as compact JSON (the annotation)."""
    prev = state.previous
    data: Obj = {
        "v": 1,
        "behavior": {
            name: {
                "r": [[round(r.timestamp, 3), r.replicas] for r in s.recommendations],
                "e": [[round(e.timestamp, 3), e.change] for e in s.events],
            }
            for name, s in sorted(state.behavior.items())
        },
    }
    if prev is not None:
        data["prev"] = {
            "t": round(prev.timestamp, 3),
            "p": prev.private_rate,
            "n": prev.normal_rate,
        }
    return json.dumps(data, separators=(",", ":"))


def load_state(text: str | None, last: ScaleDecision | None) -> ScalerState:
    """Inverse of :func:`dump_state`; a missing or unreadable annotation starts afresh."""
    try:
        data = json.loads(text) if text else {}
        behavior = {
            name: BehaviorState(
                tuple(Recommendation(float(t), int(n)) for t, n in s.get("r", [])),
                tuple(ScaleEvent(float(t), int(c)) for t, c in s.get("e", [])),
            )
            for name, s in (data.get("behavior") or {}).items()
        }
        prev = data.get("prev")
        previous = (
            MetricsSnapshot(float(prev["t"]), (), prev.get("p"), prev.get("n")) if prev else None
        )
    except (ValueError, TypeError, KeyError, AttributeError):
        log.warning("Ignored an unreadable %s annotation", ANNOTATION_STATE)
        behavior, previous = {}, None
    return ScalerState(behavior, last, previous)


def _stamp(now: float) -> str:
    return datetime.fromtimestamp(now, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _parse_stamp(text: str | None) -> float:
    if not text:
        return 0.0
    try:
        return datetime.strptime(text, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=UTC).timestamp()
    except ValueError:
        return 0.0


def _current(
    spec: ScalingSpec, module: SoftwareModule, pools: Sequence[Pool], status: Obj
) -> dict[str, int]:
    """Replicas per pool as last decided (status.scaling), or the starting point."""
    scaling = status.get("scaling") or {}
    if scaling:
        if pools and pools[0].name == ALL:
            return {ALL: int(scaling.get("desiredReplicas", 0))}
        have = {p.get("tier"): int(p.get("replicas", 0)) for p in scaling.get("pools") or []}
        return {p.name: have.get(p.name, p.min_replicas) for p in pools}
    out = {}
    for k, p in enumerate(pools):
        start = module.spec.replicas if k == 0 else p.min_replicas
        out[p.name] = min(max(start, p.min_replicas), p.max_replicas)
    return out


def _running(pod: Mapping[str, Any]) -> bool:
    st = pod.get("status") or {}
    if (pod.get("metadata") or {}).get("deletionTimestamp") or st.get("phase") != "Running":
        return False
    conds = {c.get("type"): c.get("status") for c in st.get("conditions") or []}
    return bool(conds.get("Ready", "True") == "True")


def _ready_by_pool(pods: Sequence[Obj], pools: Sequence[Pool]) -> dict[str, int]:
    out = {p.name: 0 for p in pools}
    for pod in pods:
        if not _running(pod):
            continue
        tier = ((pod.get("metadata") or {}).get("labels") or {}).get(LABEL_TIER, "")
        name = ALL if ALL in out else tier
        if name in out:
            out[name] += 1
    return out


# --------------------------------------------------------------------------- metrics


@dataclass
class _Read:
    tiers: dict[str, TierMetrics]
    private_rate: float | None = None
    normal_rate: float | None = None
    slo_seconds: float | None = None
    problem: str = ""  # PrometheusUnreachable | NoData | InvalidSLOQuery
    message: str = ""


def _read_metrics(
    module: SoftwareModule,
    spec: ScalingSpec,
    pools: Sequence[Pool],
    current: Mapping[str, int],
    ready: Mapping[str, int],
    pods: Sequence[Obj],
    deps: ScalingDeps,
) -> _Read:
    name = module.metadata.name
    ns = module.metadata.namespace or "default"
    obj = f"SoftwareModule/{name}"
    prom = deps.prometheus
    slo = spec.slo
    field_ = QUERY_FIELD if slo and slo.query else "spec.scaling.slo.metric"

    def q(promql: str) -> float | None:
        return prom.query_value(promql, obj=obj, field=field_)

    def slo_of(tier: str | None) -> float | None:
        assert slo is not None
        if slo.query:
            return q(slo.query)
        assert slo.metric is not None
        return q(
            contract.slo_query(
                slo.metric,
                module=name,
                namespace=ns,
                percentile=slo.percentile,
                window_seconds=deps.slo_window_seconds,
                tier=tier,
            )
        )

    def base(p: Pool, **kw: Any) -> TierMetrics:
        return TierMetrics(p.name, current[p.name], min(ready[p.name], current[p.name]), **kw)

    out = _Read({p.name: base(p) for p in pools})
    try:
        if spec.mode is Mode.PREDICTIVE:
            labels = contract.selector({"module": name, "namespace": ns})
            served, rejected = contract.REQUESTS_SERVED, contract.REQUESTS_REJECTED
            present = q(f"count({served}{labels}) or count({rejected}{labels})")
            if present is None:
                out.problem, out.message = (
                    "NoData",
                    (f"no {served} or {rejected} samples for module={name!r}, namespace={ns!r}"),
                )
                return out
            rates = [
                q(contract.offered_rate_query(
                    module=name, namespace=ns, privacy=privacy,
                    window_seconds=deps.rate_window_seconds,
                ))
                for privacy in ("private", "normal")
            ]  # fmt: skip
            out.private_rate, out.normal_rate = rates
            if slo is not None:
                out.slo_seconds = slo_of(None)
        elif slo is not None:
            values = {p.name: slo_of(None if p.name == ALL or slo.query else p.name) for p in pools}
            if all(v is None for v in values.values()):
                what = (
                    f"the query {slo.query!r}"
                    if slo.query
                    else (
                        f"{slo.metric.histogram if slo.metric else ''} for module={name!r}, "
                        f"namespace={ns!r}"
                    )
                )
                out.problem, out.message = "NoData", f"Prometheus has no samples of {what}"
                return out
            # A pool without samples while another has them serves nothing: no latency pressure.
            out.tiers = {p.name: base(p, slo_value_seconds=values[p.name] or 0.0) for p in pools}
            out.slo_seconds = max(v for v in values.values() if v is not None)
        else:
            target = spec.target_cpu_utilization_percent or 80
            cpu = {p.name: _cpu(q, ns, [pod for pod in pods if _in_pool(pod, p.name)], deps)
                   for p in pools}  # fmt: skip
            if all(v is None for v in cpu.values()):
                out.problem, out.message = (
                    "NoData",
                    (
                        "no CPU samples (container_cpu_usage_seconds_total) for the pods of "
                        f"{name}; target {target}%"
                    ),
                )
                return out
            out.tiers = {p.name: base(p, cpu_utilization=cpu[p.name] or 0.0) for p in pools}
    except InvalidSpec as exc:
        out.problem, out.message = "InvalidSLOQuery", f"{exc.field}: {exc.message}"
    except DependencyUnavailable as exc:
        out.problem, out.message = "PrometheusUnreachable", str(exc)
    return out


def _in_pool(pod: Mapping[str, Any], pool: str) -> bool:
    tier = ((pod.get("metadata") or {}).get("labels") or {}).get(LABEL_TIER, "")
    return pool == ALL or tier == pool


def _cpu(q: Any, ns: str, pods: Sequence[Obj], deps: ScalingDeps) -> float | None:
    names = [p["metadata"]["name"] for p in pods if _running(p)]
    if not names:
        return None
    sel = contract.selector({"namespace": ns})[:-1] + f',pod=~"{"|".join(names)}"}}'
    usage = q(
        f'sum(rate(container_cpu_usage_seconds_total{sel[:-1]},container!=""}}'
        f"[{deps.cpu_window_seconds}s]))"
    )
    requests = q(f'sum(kube_pod_container_resource_requests{sel[:-1]},resource="cpu"}})')
    if usage is None or not requests:
        return None
    return float(usage / requests)


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
    status: Obj = dict(module.get("status") or {})
    old_scaling: Obj = status.get("scaling") or {}
    pools = pools_for(mod)
    safety = mod.spec.taxonomy.safety is SafetyClass.RELEVANT
    current = _current(spec, mod, pools, status)
    pods = deps.kube.list_pods(ns, {LABEL_MODULE: name, LABEL_MANAGED_BY: MANAGER})
    ready = _ready_by_pool(pods, pools)
    last = (
        ScaleDecision(
            _parse_stamp(old_scaling.get("lastDecisionTime")),
            dict(current),
            str(old_scaling.get("reason", "")),
            not old_scaling.get("metricsAvailable", True),
        )
        if old_scaling
        else None
    )
    state = load_state((meta.get("annotations") or {}).get(ANNOTATION_STATE), last)

    read = _read_metrics(mod, spec, pools, current, ready, pods, deps)
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
        behavior=spec.resolved_behavior(),
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
    old_conds = status.get("conditions") or []
    ours = {COND_SCALING, COND_METRICS}
    merged = [c for c in old_conds if c.get("type") not in ours] + merge_conditions(
        [c for c in old_conds if c.get("type") in ours], conds
    )
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
        "lastDecisionTime": _stamp(now),
        "lastScaleTime": _stamp(now) if changed else old_scaling.get("lastScaleTime"),
        "observedSloMillis": slo_millis,
        **_admission_forecast(read.private_rate, read.normal_rate, pools, replicas),
    }
    deps.kube.patch_module_status(ns, name, {"scaling": new_scaling, "conditions": merged})
    if not read.problem:
        deps.kube.patch_module_annotations(ns, name, {ANNOTATION_STATE: dump_state(new_state)})
    _events(module, deps, old_conds, read, pools, current, replicas, before_total, total, reason)
    if changed:
        log.info("Scaled SoftwareModule %s/%s: %s (%s)", ns, name,
                 _summary(pools, current, replicas), reason)  # fmt: skip
    return Outcome(replicas, total, changed, not read.problem, reason, read.problem)


def _events(
    module: Mapping[str, Any],
    deps: ScalingDeps,
    old_conds: Sequence[Mapping[str, Any]],
    read: _Read,
    pools: Sequence[Pool],
    current: Mapping[str, int],
    replicas: Mapping[str, int],
    before_total: int,
    total: int,
    reason: str,
) -> None:
    before = {c.get("type"): c for c in old_conds}.get(COND_METRICS) or {}
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
