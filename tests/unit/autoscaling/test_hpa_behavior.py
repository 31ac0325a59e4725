"""The HPA behaviour engine against horizontal.go and the Kubernetes documentation examples."""

from fogfleet.autoscaling.behavior import (
    DEFAULT_BEHAVIOR,
    TINYKUBE_BEHAVIOR,
    Behavior,
    BehaviorState,
    PolicyType,
    Recommendation,
    ScaleEvent,
    ScalingPolicy,
    ScalingRules,
    SelectPolicy,
    normalize,
    scale_down_limit,
    scale_up_limit,
    stabilize,
)

# Kubernetes docs, "Scaling Policies": 4 pods or 10 % per minute, selectPolicy Max.
DOCS_DOWN = ScalingRules(
    0,
    (ScalingPolicy(PolicyType.PODS, 4, 60), ScalingPolicy(PolicyType.PERCENT, 10, 60)),
)


def test_docs_example_percent_policy_wins_above_forty_replicas() -> None:
    # "with 80 replicas ... reduced by 8 replicas in the first step"
    assert scale_down_limit(80, (), DOCS_DOWN, now=0.0) == 72
    # "when the number of replicas is 72, 10% of the pods is 7.2 but ... rounded up to 8"
    assert scale_down_limit(72, (), DOCS_DOWN, now=0.0) == 64


def test_docs_example_pods_policy_wins_below_forty_replicas() -> None:
    assert scale_down_limit(30, (), DOCS_DOWN, now=0.0) == 26


def test_min_select_policy_picks_the_smallest_change() -> None:
    rules = ScalingRules(0, DOCS_DOWN.policies, SelectPolicy.MIN)
    assert scale_down_limit(80, (), rules, now=0.0) == 76


def test_disabled_direction_keeps_the_current_count() -> None:
    rules = ScalingRules(0, DOCS_DOWN.policies, SelectPolicy.DISABLED)
    assert scale_down_limit(80, (), rules, now=0.0) == 80
    assert scale_up_limit(80, (), rules, now=0.0) == 80


def test_scale_up_percent_rounds_up_from_the_period_start() -> None:
    rules = TINYKUBE_BEHAVIOR.scale_up  # +100 % per 30 s
    assert scale_up_limit(5, (), rules, now=100.0) == 10
    # 5 added 10 s ago: the period started at 5 replicas, so 10 is still the limit
    assert scale_up_limit(10, (ScaleEvent(90.0, 5),), rules, now=100.0) == 10
    # once the event is older than the period it no longer counts
    assert scale_up_limit(10, (ScaleEvent(60.0, 5),), rules, now=100.0) == 20


def test_scale_down_in_the_period_counts_against_scale_up() -> None:
    rules = ScalingRules(0, (ScalingPolicy(PolicyType.PODS, 4, 60),))
    # went 10 -> 6 twenty seconds ago: period start is 10, so up to 14 is allowed
    assert scale_up_limit(6, (ScaleEvent(80.0, -4),), rules, now=100.0) == 14


def test_scale_down_window_takes_the_highest_recent_recommendation() -> None:
    recs = (Recommendation(0.0, 10), Recommendation(100.0, 8), Recommendation(200.0, 6))
    assert stabilize(3, 10, recs, TINYKUBE_BEHAVIOR, now=250.0) == 10
    # after 300 s the 10 left the window; 8 (t=100) is still in it
    assert stabilize(3, 10, recs, TINYKUBE_BEHAVIOR, now=301.0) == 8


def test_scale_up_window_takes_the_lowest_recent_recommendation() -> None:
    recs = (Recommendation(0.0, 5), Recommendation(30.0, 9))
    assert stabilize(12, 5, recs, TINYKUBE_BEHAVIOR, now=50.0) == 5
    assert stabilize(12, 5, recs, TINYKUBE_BEHAVIOR, now=61.0) == 9
    # the window is strict, as Go's time.After: a recommendation exactly 60 s old is out
    assert stabilize(12, 5, recs, TINYKUBE_BEHAVIOR, now=59.9) == 5
    assert stabilize(12, 5, recs, TINYKUBE_BEHAVIOR, now=60.0) == 9


def test_normalize_follows_tinykube_scale_up_over_time() -> None:
    state, replicas = BehaviorState(), 5
    for t in range(0, 300, 15):  # steady at 5 for five minutes: the HPA syncs every 15 s
        step = normalize(5, 5, state, TINYKUBE_BEHAVIOR, min_replicas=1, max_replicas=17, now=t)
        state = step.state
    seen = []
    for t in range(300, 400, 15):  # the load surges at t = 300
        step = normalize(
            40, replicas, state, TINYKUBE_BEHAVIOR, min_replicas=1, max_replicas=17, now=t
        )
        state, replicas = step.state, step.replicas
        seen.append(replicas)
    # held while the last low recommendation (t = 285) is inside the 60 s window, then
    # +100 % per 30 s (counted from the period start) up to the maximum
    assert seen == [5, 5, 5, 10, 10, 17, 17]


def test_normalize_brings_an_out_of_range_count_back_without_metrics() -> None:
    step = normalize(
        3, 30, BehaviorState(), DEFAULT_BEHAVIOR, min_replicas=1, max_replicas=20, now=0
    )
    assert (step.replicas, step.reason) == (20, "TooManyReplicas")
    step = normalize(
        9, 0, BehaviorState(), DEFAULT_BEHAVIOR, min_replicas=2, max_replicas=20, now=0
    )
    assert step.replicas == 2


def test_normalize_never_leaves_the_bounds() -> None:
    behavior = Behavior(
        ScalingRules(0, (ScalingPolicy(PolicyType.PODS, 100, 1),)),
        ScalingRules(0, (ScalingPolicy(PolicyType.PERCENT, 100, 1),)),
    )
    state, replicas = BehaviorState(), 3
    for t, desired in enumerate([50, 0, 7, 100, 1, 0]):
        step = normalize(
            desired, replicas, state, behavior, min_replicas=2, max_replicas=9, now=float(t * 10)
        )
        state, replicas = step.state, step.replicas
        assert 2 <= replicas <= 9


def test_normalize_forgets_old_history() -> None:
    state = BehaviorState(recommendations=(Recommendation(0.0, 50),), events=(ScaleEvent(0.0, 5),))
    step = normalize(8, 4, state, TINYKUBE_BEHAVIOR, min_replicas=1, max_replicas=60, now=1000.0)
    assert step.replicas == 8
    assert [r.timestamp for r in step.state.recommendations] == [1000.0]
    assert step.state.events == (ScaleEvent(1000.0, 4),)
