"""The metrics contract's names and PromQL builders."""

import pytest

from fogfleet.api.v1alpha1.scaling import SloMetric
from fogfleet.contract import metrics as c


def test_names_follow_prometheus_conventions() -> None:
    assert c.CYCLE_TIME.endswith("_seconds") and c.RESPONSE_TIME.endswith("_seconds")
    for counter in (c.MISSED_CYCLES, c.REQUESTS_SERVED, c.REQUESTS_REJECTED):
        assert counter.endswith("_total")
    names = [c.CYCLE_TIME, c.MISSED_CYCLES, c.REQUESTS_SERVED, c.REQUESTS_REJECTED,
             c.RESPONSE_TIME, c.QUEUE_LENGTH, c.REPLICAS]  # fmt: skip
    assert len(set(names)) == 7 and all(n.startswith("fogfleet_") for n in names)


def test_slo_query_is_the_standard_histogram_quantile() -> None:
    query = c.slo_query(
        SloMetric.RESPONSE_TIME, module="detector", namespace="fleet", percentile=95
    )
    assert query == (
        "histogram_quantile(0.95, sum by (le) (rate(fogfleet_response_time_seconds_bucket"
        '{module="detector",namespace="fleet"}[60s])))'
    )


def test_slo_query_can_select_a_tier_and_window() -> None:
    query = c.slo_query(
        SloMetric.CYCLE_TIME,
        module="m",
        namespace="n",
        percentile=99,
        window_seconds=30,
        tier="edge",
    )
    assert (
        'tier="edge"' in query and "[30s]" in query and query.startswith("histogram_quantile(0.99,")
    )
    assert "fogfleet_cycle_time_seconds_bucket" in query


def test_label_values_are_escaped() -> None:
    assert c.selector({"module": 'a"b\\c'}) == '{module="a\\"b\\\\c"}'
    with pytest.raises(ValueError):
        c.selector({"bad-name": "x"})


def test_percentile_must_be_a_percentage() -> None:
    with pytest.raises(ValueError):
        c.slo_query(SloMetric.RESPONSE_TIME, module="m", namespace="n", percentile=100)


def test_offered_rate_adds_served_and_rejected() -> None:
    query = c.offered_rate_query(module="m", namespace="n", privacy="private")
    assert c.REQUESTS_SERVED in query and c.REQUESTS_REJECTED in query
    assert query.count('privacy="private"') == 2
