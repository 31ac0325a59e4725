"""Queueing formulas on tiny instances computed by hand (textbook M/M/1, M/M/2, M/M/1/K)."""

import math

import pytest

from fogfleet.autoscaling import queueing as q


def test_erlang_c_of_two_servers_at_load_one_is_one_third() -> None:
    # C(2, 1) = (1/2 * 2/(2-1)) / (1 + 1 + 1/2 * 2) = 1/3
    assert q.erlang_c(2, 1.0) == pytest.approx(1 / 3)
    assert q.erlang_c(1, 0.5) == pytest.approx(0.5)  # M/M/1: P(wait) = rho
    assert q.erlang_c(3, 3.0) == 1.0


def test_mm1_mean_and_tail_are_textbook() -> None:
    lam, mu = 3.0, 5.0
    assert q.mmk_mean_response_seconds(lam, mu, 1) == pytest.approx(1 / (mu - lam))
    for t in (0.1, 0.5, 2.0):
        assert q.mmk_response_sf(t, lam, mu, 1) == pytest.approx(math.exp(-(mu - lam) * t))
    assert q.response_quantile_seconds(0.9, lam, mu, 1) == pytest.approx(math.log(10) / 2)


def test_mm2_mean_response_is_four_thirds() -> None:
    # lam = mu = 1, k = 2: W_q = C / (k mu - lam) = 1/3, W = 1/3 + 1
    assert q.mmk_mean_response_seconds(1.0, 1.0, 2) == pytest.approx(4 / 3)


def test_tail_integrates_to_the_mean() -> None:
    lam, mu, k = 7.0, 2.0, 5
    dt = 0.001
    area = sum(q.mmk_response_sf(i * dt, lam, mu, k) for i in range(20_000)) * dt
    assert area == pytest.approx(q.mmk_mean_response_seconds(lam, mu, k), rel=1e-3)


def test_unstable_pool_has_infinite_response() -> None:
    assert q.mmk_mean_response_seconds(10.0, 2.0, 5) == math.inf
    assert q.mmk_response_sf(1.0, 10.0, 2.0, 5) == 1.0


def test_mm1_setup_mean_adds_the_setup_time() -> None:
    # M/M/1 with exponential setup: E[T] = 1/(mu - lam) + E[setup] (Welch's decomposition)
    assert q.mmk_setup_mean_response_seconds(0.5, 1.0, 1, 2.0) == pytest.approx(4.0, rel=1e-6)


def test_setup_model_reduces_to_mmk_as_setup_vanishes() -> None:
    assert q.mmk_setup_mean_response_seconds(3.0, 1.0, 5, 1e-4) == pytest.approx(
        q.mmk_mean_response_seconds(3.0, 1.0, 5), rel=1e-3
    )
    assert q.mean_response_seconds(3.0, 1.0, 5, setup_seconds=0.0) == pytest.approx(
        q.mmk_mean_response_seconds(3.0, 1.0, 5)
    )


def test_setup_tail_is_exact_for_one_server_and_worse_than_warm() -> None:
    # M/M/1/setup: T = Exp(mu - lam) + Exp(1/setup) exactly
    lam, mu, setup, t = 0.5, 1.0, 4.0, 4.0
    a, b = mu - lam, 1 / setup
    exact = (a * math.exp(-b * t) - b * math.exp(-a * t)) / (a - b)
    assert q.mmk_setup_response_sf(t, lam, mu, 1, setup) == pytest.approx(exact, rel=1e-4)
    assert q.mmk_setup_response_sf(0.5, 4.0, 1.0, 6, 0.5) > q.mmk_response_sf(0.5, 4.0, 1.0, 6)


def test_min_replicas_is_the_smallest_feasible_count() -> None:
    lam, mu, slo, pct = 50.0, 8.0, 0.5, 0.95
    k = q.min_replicas_for_slo(lam, mu, slo, pct)
    assert k is not None
    assert q.mmk_response_sf(slo, lam, mu, k) <= 1 - pct
    assert q.mmk_response_sf(slo, lam, mu, k - 1) > 1 - pct


def test_min_replicas_is_none_when_service_alone_is_too_slow() -> None:
    # P(S > 0.1) = exp(-1) > 5 %: no number of replicas helps
    assert q.min_replicas_for_slo(1.0, 10.0, 0.1, 0.95) is None
    assert q.min_replicas_for_slo(500.0, 8.0, 0.5, 0.95, k_max=10) is None


def test_admission_capacity_follows_eq3_on_the_queue() -> None:
    # k = 2, mu = 1, target 3 s: n admitted iff (n - 1)/2 + 1 <= 3, i.e. n <= 5
    assert q.admission_capacity(2, 1.0, 3.0) == 6
    assert q.admission_capacity(2, 1.0, 0.5) == 0


def test_admission_refusals_are_mm1k_blocking() -> None:
    # k = 1, mu = 1, target 3 s -> K = 3; M/M/1/3 at rho = 0.5: (1-r) r^3 / (1 - r^4)
    rho = 0.5
    expected = (1 - rho) * rho**3 / (1 - rho**4)
    assert q.admission_reject_probability(0.5, 1.0, 1, 3.0) == pytest.approx(expected)


def test_min_replicas_for_admission_is_minimal() -> None:
    k = q.min_replicas_for_admission(60.0, 6.0, 0.35, 0.01)
    assert k is not None
    assert q.admission_reject_probability(60.0, 6.0, k, 0.35) <= 0.01
    assert q.admission_reject_probability(60.0, 6.0, k - 1, 0.35) > 0.01


def test_reservation_without_reserve_is_plain_admission() -> None:
    cap = q.admission_capacity(4, 3.0, 0.8)
    p, n = q.reservation_blocking(4.0, 6.0, 3.0, 4, cap, cap)
    assert p == pytest.approx(n)
    assert p == pytest.approx(q.admission_reject_probability(10.0, 3.0, 4, 0.8))


def test_reservation_protects_private_traffic() -> None:
    cap = q.admission_capacity(4, 3.0, 0.8)
    plain, _ = q.reservation_blocking(4.0, 8.0, 3.0, 4, cap, cap)
    private, normal = q.reservation_blocking(4.0, 8.0, 3.0, 4, cap, cap - 2)
    assert private < plain < normal


def test_max_arrival_rate_is_the_inverse_of_min_replicas() -> None:
    lam = q.max_arrival_rate_for_slo(6.0, 10, 0.6, 0.9)
    assert q.mmk_response_sf(0.6, lam * 0.999, 6.0, 10) <= 0.1
    assert q.mmk_response_sf(0.6, lam * 1.01, 6.0, 10) > 0.1
