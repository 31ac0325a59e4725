"""The autoscaler's pools: a shared module's replicas per tier (tinyKube III-B), from its spec.

A pool has bounds, the service rate of one replica (mu), the response-time target and
percentile, the setup time of a new replica and the robot round trip to its tier; the policy
(``policy.decide``) sizes every pool, edge before cloud.
"""

from __future__ import annotations

from fogfleet.api.v1alpha1.base import parse_millis
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.domain.network import DEFAULT_UPLINK, path

from .policy import Pool

__all__ = ["ALL", "DISPATCH_RESERVE", "pools_for", "service_rate"]

DISPATCH_RESERVE = 2  # edge places kept for private requests (the bench's and the twin's)
ALL = "all"  # the single pool of a module without spec.scaling.pools
_TIER_ORDER = {Tier.EDGE: 0, Tier.CLOUD: 1}


def service_rate(module: SoftwareModule) -> float:
    """Requests/s one replica completes (mu): 1 / mean execution time of the profile.

    The ``default`` hardware row if there is one, else the median row: a pool spans several
    hardware types, and the median is robust to one very fast or very slow machine."""
    rows = [r for r in module.spec.profile if r.hardware_type == "default"] or list(
        module.spec.profile
    )
    means = sorted(parse_millis(r.mean_millis) for r in rows)
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
    target = parse_millis(spec.slo.target_millis) if spec.slo else module.spec.cycle_seconds
    setup = parse_millis(spec.setup_millis or 0)
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
                parse_millis(p.slo_target_millis) if p.slo_target_millis else target,
                pct,
                parse_millis(p.setup_millis) if p.setup_millis is not None else setup,
                _round_trip(Tier(p.tier.value)),
                p.private_allowed,
            )
        )
    return out
