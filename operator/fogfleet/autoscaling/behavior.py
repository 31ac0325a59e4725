"""The Kubernetes HPA's ``behavior`` engine: stabilisation windows and rate-limit policies.

A faithful, pure re-implementation of ``pkg/controller/podautoscaler/horizontal.go``
(``normalizeDesiredReplicasWithBehaviors`` and the functions it calls, Kubernetes >= 1.26), so
that fogfleet's own scaler, the benchmark's baseline and a real HPA configured with the same
``behavior`` block move replicas identically. Time is passed in explicitly (seconds, any epoch)
and the engine's memory (past recommendations and scale events) is an immutable
:class:`BehaviorState` that every step returns anew.

One step, in the HPA's order:

1. **Stabilise** the metric's recommendation ``desired``: ``up = min(desired, recommendations
   newer than the scale-up window)``, ``down = max(desired, recommendations newer than the
   scale-down window)``; the result is ``current`` brought into ``[up, down]``. "Newer" is
   strict (``timestamp > now - window``), as Go's ``After``.
2. **Rate-limit**: for each policy, ``periodStart = current - added + deleted`` over the policy's
   period; scale up to ``periodStart + value`` (Pods) or ``ceil(periodStart * (1 + value/100))``
   (Percent); scale down to ``periodStart - value`` or ``int(periodStart * (1 - value/100))``
   (truncated, as Go's ``int32()``). ``selectPolicy: Max`` picks the policy allowing the largest
   change, ``Min`` the smallest, ``Disabled`` forbids the direction.
3. Clamp to ``[minReplicas, maxReplicas]`` (the limit never forces a change against the
   direction of scaling).

The tinyKube preset is the auto-scaler of seeds/tinykube-cloud-edge-resource-management.txt,
section IV-C ("Design of a Straightforward Auto-Scaler"): scale up by at most 100 % of the
current replicas per 30 s with a 60 s stabilisation window; scale down by at most 50 % per 60 s
with a 5 min stabilisation window.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from fogfleet.api.v1alpha1.scaling import (
    BehaviorSpec,
    PolicyType,
    ScalingRulesSpec,
    ScalingSpec,
    SelectPolicy,
)

__all__ = [
    "DEFAULT_BEHAVIOR",
    "FAST_BEHAVIOR",
    "PRESETS",
    "TINYKUBE_BEHAVIOR",
    "Behavior",
    "BehaviorState",
    "PolicyType",
    "Recommendation",
    "ScaleEvent",
    "ScalingPolicy",
    "ScalingRules",
    "SelectPolicy",
    "Step",
    "normalize",
    "resolve_behavior",
    "resolve_rules",
    "scale_down_limit",
    "scale_up_limit",
    "stabilize",
]


@dataclass(frozen=True)
class ScalingPolicy:
    """At most ``value`` pods (or percent of the replicas) change per ``period_seconds``."""

    type: PolicyType
    value: int
    period_seconds: int


@dataclass(frozen=True)
class ScalingRules:
    """One direction of an HPA ``behavior`` block."""

    stabilization_window_seconds: int
    policies: tuple[ScalingPolicy, ...]
    select_policy: SelectPolicy = SelectPolicy.MAX

    @property
    def longest_period_seconds(self) -> int:
        return max((p.period_seconds for p in self.policies), default=0)


@dataclass(frozen=True)
class Behavior:
    scale_up: ScalingRules
    scale_down: ScalingRules


DEFAULT_BEHAVIOR = Behavior(
    # The HPA's defaults when ``behavior`` is not set (autoscaling/v2 API reference).
    scale_up=ScalingRules(
        0,
        (ScalingPolicy(PolicyType.PERCENT, 100, 15), ScalingPolicy(PolicyType.PODS, 4, 15)),
    ),
    scale_down=ScalingRules(300, (ScalingPolicy(PolicyType.PERCENT, 100, 15),)),
)

TINYKUBE_BEHAVIOR = Behavior(
    # tinyKube section IV-C: "+100 % within a 30-second window", "stabilization window of
    # 60 seconds"; "-50 % of the current replicas in a 60-second period", "stabilization
    # window of 5 minutes".
    scale_up=ScalingRules(60, (ScalingPolicy(PolicyType.PERCENT, 100, 30),)),
    scale_down=ScalingRules(300, (ScalingPolicy(PolicyType.PERCENT, 50, 60),)),
)

FAST_BEHAVIOR = Behavior(
    # fogfleet's own setting (``preset: fast``), the one `make bench` measures its reactive-slo
    # and predictive modes with: follow the recommendation up at once; down after 30 s, by half.
    scale_up=ScalingRules(0, (ScalingPolicy(PolicyType.PODS, 100, 1),)),
    scale_down=ScalingRules(30, (ScalingPolicy(PolicyType.PERCENT, 50, 30),)),
)

PRESETS = {"tinykube": TINYKUBE_BEHAVIOR, "fast": FAST_BEHAVIOR}


@dataclass(frozen=True)
class Recommendation:
    timestamp: float
    replicas: int


@dataclass(frozen=True)
class ScaleEvent:
    """A change actually applied: ``change`` > 0 added replicas, < 0 removed them."""

    timestamp: float
    change: int


@dataclass(frozen=True)
class BehaviorState:
    """What the HPA remembers per target: raw recommendations and applied scale events."""

    recommendations: tuple[Recommendation, ...] = ()
    events: tuple[ScaleEvent, ...] = ()


@dataclass(frozen=True)
class Step:
    """Result of :func:`normalize`: the replicas to set, why, and the new memory."""

    replicas: int
    reason: str
    state: BehaviorState = field(repr=False)


def stabilize(
    desired: int,
    current: int,
    recommendations: Iterable[Recommendation],
    behavior: Behavior,
    now: float,
) -> int:
    """The stabilised recommendation (horizontal.go ``stabilizeRecommendationWithBehaviors``)."""
    up_cutoff = now - behavior.scale_up.stabilization_window_seconds
    down_cutoff = now - behavior.scale_down.stabilization_window_seconds
    up = down = desired
    for rec in recommendations:
        if rec.timestamp > up_cutoff:
            up = min(up, rec.replicas)
        if rec.timestamp > down_cutoff:
            down = max(down, rec.replicas)
    return min(max(current, up), down)


def _change_in_period(
    events: Iterable[ScaleEvent], period_seconds: int, now: float
) -> tuple[int, int]:
    cutoff = now - period_seconds
    added = deleted = 0
    for event in events:
        if event.timestamp > cutoff:
            if event.change > 0:
                added += event.change
            else:
                deleted -= event.change
    return added, deleted


def scale_up_limit(
    current: int, events: Iterable[ScaleEvent], rules: ScalingRules, now: float
) -> int:
    """Most replicas the policies allow now (``calculateScaleUpLimitWithScalingRules``)."""
    if rules.select_policy is SelectPolicy.DISABLED:
        return current
    history = tuple(events)
    proposals = []
    for policy in rules.policies:
        added, deleted = _change_in_period(history, policy.period_seconds, now)
        start = current - added + deleted
        if policy.type is PolicyType.PODS:
            proposals.append(start + policy.value)
        else:
            proposals.append(math.ceil(start * (1 + policy.value / 100)))
    if not proposals:
        return current
    return min(proposals) if rules.select_policy is SelectPolicy.MIN else max(proposals)


def scale_down_limit(
    current: int, events: Iterable[ScaleEvent], rules: ScalingRules, now: float
) -> int:
    """Fewest replicas the policies allow now (``calculateScaleDownLimitWithBehaviors``)."""
    if rules.select_policy is SelectPolicy.DISABLED:
        return current
    history = tuple(events)
    proposals = []
    for policy in rules.policies:
        added, deleted = _change_in_period(history, policy.period_seconds, now)
        start = current - added + deleted
        if policy.type is PolicyType.PODS:
            proposals.append(start - policy.value)
        else:
            proposals.append(int(start * (1 - policy.value / 100)))
    if not proposals:
        return current
    return max(proposals) if rules.select_policy is SelectPolicy.MIN else min(proposals)


def _limit_rate(
    desired: int,
    current: int,
    events: tuple[ScaleEvent, ...],
    behavior: Behavior,
    min_replicas: int,
    max_replicas: int,
    now: float,
) -> tuple[int, str]:
    if desired > current:
        limit = max(scale_up_limit(current, events, behavior.scale_up, now), current)
        if max_replicas > limit:
            allowed, reason = limit, "ScaleUpLimit"
        else:
            allowed, reason = max_replicas, "TooManyReplicas"
        if desired > allowed:
            return allowed, reason
    elif desired < current:
        limit = min(scale_down_limit(current, events, behavior.scale_down, now), current)
        if min_replicas < limit:
            allowed, reason = limit, "ScaleDownLimit"
        else:
            allowed, reason = min_replicas, "TooFewReplicas"
        if desired < allowed:
            return allowed, reason
    return desired, "DesiredWithinRange"


def normalize(
    desired: int,
    current: int,
    state: BehaviorState,
    behavior: Behavior,
    *,
    min_replicas: int,
    max_replicas: int,
    now: float,
) -> Step:
    """One HPA reconcile from a metric recommendation ``desired`` to the replicas to set.

    Mirrors ``reconcileAutoscaler``: a target outside ``[min, max]`` is first brought back
    inside without consulting the metric; otherwise the recommendation is stabilised, then
    rate-limited. The new recommendation and (if the count changes) the scale event are
    recorded in the returned state; entries older than every window/period are dropped.
    """
    if min_replicas > max_replicas:
        raise ValueError(f"min_replicas {min_replicas} > max_replicas {max_replicas}")
    recommendations = state.recommendations
    if current > max_replicas:
        replicas, reason = max_replicas, "TooManyReplicas"
    elif current < min_replicas:
        replicas, reason = min_replicas, "TooFewReplicas"
    else:
        stabilized = stabilize(desired, current, recommendations, behavior, now)
        horizon = max(
            behavior.scale_up.stabilization_window_seconds,
            behavior.scale_down.stabilization_window_seconds,
        )
        recommendations = (
            *(r for r in recommendations if r.timestamp > now - horizon),
            Recommendation(now, desired),
        )
        replicas, reason = _limit_rate(
            stabilized, current, state.events, behavior, min_replicas, max_replicas, now
        )
        if reason == "DesiredWithinRange" and stabilized != desired:
            reason = "ScaleUpStabilized" if desired > stabilized else "ScaleDownStabilized"
    events = state.events
    if replicas != current:
        keep = max(
            behavior.scale_up.longest_period_seconds, behavior.scale_down.longest_period_seconds
        )
        events = (
            *(e for e in events if e.timestamp > now - keep),
            ScaleEvent(now, replicas - current),
        )
    return Step(replicas, reason, BehaviorState(recommendations, events))


def resolve_rules(spec: ScalingRulesSpec | None, default: ScalingRules) -> ScalingRules:
    """One direction of a spec's ``behavior``; unset fields take ``default``'s (the HPA's)."""
    if spec is None:
        return default
    return ScalingRules(
        default.stabilization_window_seconds
        if spec.stabilization_window_seconds is None
        else spec.stabilization_window_seconds,
        default.policies
        if spec.policies is None
        else tuple(ScalingPolicy(p.type, p.value, p.period_seconds) for p in spec.policies),
        default.select_policy if spec.select_policy is None else spec.select_policy,
    )


def resolve_behavior(spec: ScalingSpec | BehaviorSpec | None) -> Behavior:
    """The engine's Behavior for a scaling spec: a preset (``tinykube``, ``fast``) fills the
    directions left unset, otherwise the HPA's defaults do."""
    behavior = spec.behavior if isinstance(spec, ScalingSpec) else spec
    behavior = behavior or BehaviorSpec()
    base = PRESETS.get(behavior.preset or "", DEFAULT_BEHAVIOR)
    return Behavior(
        resolve_rules(behavior.scale_up, base.scale_up),
        resolve_rules(behavior.scale_down, base.scale_down),
    )
