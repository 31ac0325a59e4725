"""What the scaling controller reads from Prometheus: the metrics contract
(``fogfleet.contract.metrics``) for one shared module, per pool, as a MetricsSnapshot's
parts; a missing, empty or rejected query is reported (``problem``), never raised.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fogfleet.adapters.prometheus import QUERY_FIELD
from fogfleet.api.labels import LABEL_TIER
from fogfleet.api.v1alpha1.scaling import Mode, ScalingSpec
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.autoscaling.policy import Pool, TierMetrics
from fogfleet.autoscaling.pools import ALL
from fogfleet.contract import metrics as contract
from fogfleet.contract.metrics import histogram_of
from fogfleet.controllers.deps import ScalingDeps
from fogfleet.controllers.status import pod_ready
from fogfleet.errors import DependencyUnavailable, InvalidSpec

__all__ = ["MetricsRead", "read_metrics"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


@dataclass
class MetricsRead:
    tiers: dict[str, TierMetrics]
    private_rate: float | None = None
    normal_rate: float | None = None
    slo_seconds: float | None = None
    problem: str = ""  # PrometheusUnreachable | NoData | InvalidSLOQuery
    message: str = ""


def read_metrics(
    module: SoftwareModule,
    spec: ScalingSpec,
    pools: Sequence[Pool],
    current: Mapping[str, int],
    ready: Mapping[str, int],
    pods: Sequence[Obj],
    deps: ScalingDeps,
) -> MetricsRead:
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

    out = MetricsRead({p.name: base(p) for p in pools})
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
                        f"{histogram_of(slo.metric) if slo.metric else ''} for module={name!r}, "
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
    names = [p["metadata"]["name"] for p in pods if pod_ready(p)]
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
