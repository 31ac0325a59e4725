"""Response-time model of a replica pool: M/M/k and M/M/k/setup (tinyKube section III-B).

tinyKube (seeds/tinykube-cloud-edge-resource-management.txt, III-B) models every cluster as an
M/M/k/setup queue -- Poisson arrivals at rate ``lam``, exponential service at rate ``mu`` per
replica, ``k`` replicas, and a setup time for replicas that are not running yet -- and states:

* eq. 1  ``mu_eff = mu / (1 + T_setup * lam)``
* eq. 2  ``W_q = L_q / (lam * (1 - lam * mu_eff / k))``
* eq. 3  ``W = W_q + 1 / mu_eff``

As printed these cannot be used as they stand: eq. 2 is dimensionally inconsistent
(``lam * mu_eff / k`` has units s^-2; the utilisation is ``rho = lam / (k * mu)``), and eq. 1
makes every request pay the setup of a whole replica (at lam = 50/s and T_setup = 1.8 s,
``1/mu_eff`` is 91 service times). This module therefore implements the model the equations
summarise, exactly:

* **warm pool (no setup)**: Erlang C. ``P(wait) = C(k, a)`` with ``a = lam/mu``;
  ``W_q = L_q / lam = C / (k mu - lam)`` (eq. 2 with Little's law); ``W = W_q + 1/mu`` (eq. 3);
  and the full distribution ``P(T > t)``, since an SLO is a percentile, not a mean.
* **M/M/k/setup** (the class of chains analysed by Gandhi, Doroudi, Harchol-Balter and
  Scheller-Wolf, SIGMETRICS 2013): a replica is switched off when it has nothing to do and a
  job that finds no free replica starts one, which becomes usable after an exponential setup
  of mean ``T_setup``; so ``min(n, k) - i`` replicas are in setup with ``i`` on and ``n`` jobs.
  The mean response time is exact (stationary distribution of the truncated CTMC and Little's
  law); ``P(T > t)`` follows a tagged job and ignores the setups started by jobs that arrive
  after it, which can only help it -- an upper bound, i.e. a conservative SLO check. With
  ``setup_seconds = 0`` every function falls back to the warm-pool formulas.

**Admission** (tinyKube III-B) admits a request only if eq. 3, evaluated on the queue it would
join, meets its target: with ``n`` requests at ``k`` busy replicas the conditional mean is
``(n - k + 1)/(k mu) + 1/mu``. That caps the pool at ``K = k + m`` requests, turning it into
an M/M/k/K queue whose blocking probability is the share of requests admission turns away
(:func:`admission_reject_probability`).

Kubernetes Deployments keep their replicas warm, so fogfleet's predictive mode sizes the pool
with the warm-pool model for the arrival rate expected once a newly requested replica is ready
(``setup_seconds`` ahead); the setup model answers what on-demand starting would cost.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import expm_multiply, spsolve
from scipy.special import gammaln

__all__ = [
    "admission_capacity",
    "admission_reject_probability",
    "erlang_c",
    "max_arrival_rate_for_slo",
    "mean_response_seconds",
    "min_replicas_for_admission",
    "min_replicas_for_slo",
    "mmk_mean_response_seconds",
    "mmk_mean_wait_seconds",
    "mmk_response_sf",
    "mmk_setup_mean_response_seconds",
    "mmk_setup_response_sf",
    "reservation_blocking",
    "response_quantile_seconds",
    "response_sf",
]


def _check(lam: float, mu: float, k: int) -> None:
    if lam < 0 or mu <= 0 or k < 0:
        raise ValueError(f"need lam >= 0, mu > 0, k >= 0 (got lam={lam}, mu={mu}, k={k})")


def erlang_c(k: int, offered_load: float) -> float:
    """Probability that an arrival waits in M/M/k, ``C(k, a)`` with ``a = lam/mu``.

    Computed through the Erlang B recursion (stable for large ``k``); 1.0 when ``a >= k``.
    """
    if k <= 0 or offered_load >= k:
        return 1.0
    if offered_load <= 0:
        return 0.0
    b = 1.0
    for j in range(1, k + 1):
        b = offered_load * b / (j + offered_load * b)
    return k * b / (k - offered_load * (1.0 - b))


def mmk_mean_wait_seconds(lam: float, mu: float, k: int) -> float:
    """Mean queueing delay ``W_q = C(k, a) / (k mu - lam)``; ``inf`` when unstable."""
    _check(lam, mu, k)
    if lam >= k * mu:
        return math.inf
    return erlang_c(k, lam / mu) / (k * mu - lam)


def mmk_mean_response_seconds(lam: float, mu: float, k: int) -> float:
    """Mean response time ``W = W_q + 1/mu`` (tinyKube eq. 3 without setup)."""
    return mmk_mean_wait_seconds(lam, mu, k) + 1.0 / mu


def _hypoexp_sf(t: float, a: float, b: float) -> float:
    """P(X + Y > t) for independent X ~ Exp(a), Y ~ Exp(b)."""
    if abs(a - b) < 1e-9 * max(a, b):
        return (1.0 + b * t) * math.exp(-b * t)
    return (a * math.exp(-b * t) - b * math.exp(-a * t)) / (a - b)


def mmk_response_sf(t: float, lam: float, mu: float, k: int) -> float:
    """``P(T > t)`` for FCFS M/M/k: T = W_q + S, W_q = 0 w.p. 1-C else Exp(k mu - lam)."""
    _check(lam, mu, k)
    if t <= 0:
        return 1.0
    if lam >= k * mu:
        return 1.0
    c = erlang_c(k, lam / mu)
    theta = k * mu - lam
    return (1.0 - c) * math.exp(-mu * t) + c * _hypoexp_sf(t, theta, mu)


def _generator(edges: list[tuple[int, int, float]], size: int) -> sp.csr_matrix:
    """Sparse CTMC generator from (from, to, rate) edges; rows sum to zero."""
    rows, cols, rates = zip(*edges, strict=True) if edges else ((), (), ())
    q = sp.csr_matrix((rates, (rows, cols)), shape=(size, size))
    return sp.csr_matrix(q - sp.diags(np.asarray(q.sum(axis=1)).ravel()))


# --- M/M/k/setup -----------------------------------------------------------------------------


def _truncation(lam: float, mu: float, k: int, setup_seconds: float) -> int:
    rho = lam / (k * mu)
    tail = math.ceil(40.0 / -math.log(rho)) if rho > 0 else 0
    return min(k + 60 + tail + math.ceil(6 * lam * setup_seconds), 4000)


def _setup_chain(
    lam: float, mu: float, k: int, setup_seconds: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stationary distribution of the (i on, n jobs) chain; returns (pi, i, n) per state."""
    alpha = 1.0 / setup_seconds
    n_max = _truncation(lam, mu, k, setup_seconds)
    states = [(i, n) for n in range(n_max + 1) for i in range(min(n, k) + 1)]
    index = {s: j for j, s in enumerate(states)}
    edges: list[tuple[int, int, float]] = []
    for j, (i, n) in enumerate(states):
        if n < n_max:
            edges.append((j, index[(i, n + 1)], lam))
        setting_up = min(n, k) - i
        if setting_up > 0:
            edges.append((j, index[(i + 1, n)], alpha * setting_up))
        if i > 0:
            # A finishing replica takes the next waiting job, or switches off if there is none.
            target = (i, n - 1) if n - 1 >= i else (i - 1, n - 1)
            edges.append((j, index[target], mu * i))
    size = len(states)
    q = _generator(edges, size)
    # Solve pi Q = 0 with sum(pi) = 1 by replacing one balance equation.
    a = q.T.tolil()
    a[0, :] = 1.0
    rhs = np.zeros(size)
    rhs[0] = 1.0
    pi = np.clip(spsolve(a.tocsr(), rhs), 0.0, None)
    pi /= pi.sum()
    on = np.array([s[0] for s in states])
    jobs = np.array([s[1] for s in states])
    return pi, on, jobs


def mmk_setup_mean_response_seconds(lam: float, mu: float, k: int, setup_seconds: float) -> float:
    """Exact mean response time of M/M/k/setup (Little's law on the stationary chain)."""
    _check(lam, mu, k)
    if setup_seconds <= 0:
        return mmk_mean_response_seconds(lam, mu, k)
    if lam >= k * mu or k == 0:
        return math.inf
    if lam == 0:
        return setup_seconds + 1.0 / mu
    pi, _, jobs = _setup_chain(lam, mu, k, setup_seconds)
    return float(pi @ jobs) / lam


def mmk_setup_response_sf(t: float, lam: float, mu: float, k: int, setup_seconds: float) -> float:
    """Upper bound on ``P(T > t)`` in M/M/k/setup (tagged job, later setups ignored)."""
    _check(lam, mu, k)
    if setup_seconds <= 0:
        return mmk_response_sf(t, lam, mu, k)
    if t <= 0 or lam >= k * mu or k == 0:
        return 1.0
    alpha = 1.0 / setup_seconds
    if lam == 0:
        return _hypoexp_sf(t, alpha, mu)
    pi, on, jobs = _setup_chain(lam, mu, k, setup_seconds)
    w_max = int(jobs.max()) + 1
    # Transient states: (i on, w waiting up to and including the tagged job), then "in service".
    states = [(i, w) for i in range(k + 1) for w in range(1, w_max + 1)]
    index = {s: j for j, s in enumerate(states)}
    serving = len(states)
    size = serving + 1
    edges: list[tuple[int, int, float]] = []
    for j, (i, w) in enumerate(states):
        if i > 0:  # a replica finishes and takes the head of the queue
            edges.append((j, serving if w == 1 else index[(i, w - 1)], mu * i))
        setting_up = min(i + w, k) - i
        if setting_up > 0:  # a setup completes and takes the head of the queue
            edges.append((j, serving if w == 1 else index[(i + 1, w - 1)], alpha * setting_up))
    q = _generator(edges, size)
    q = q - sp.diags(np.eye(1, size, serving).ravel() * mu)  # service ends: leaves the chain
    start = np.zeros(size)
    for p, i, n in zip(pi, on, jobs, strict=True):
        # PASTA: the tagged job sees the stationary state (i, n) and queues behind n - i jobs.
        start[index[(int(i), int(n) + 1 - int(i))]] += p
    alive = expm_multiply(q.T.tocsc() * t, start)
    return float(np.clip(alive.sum(), 0.0, 1.0))


# --- choosing k --------------------------------------------------------------------------------


def response_sf(
    t: float, lam: float, mu: float, k: int, *, setup_seconds: float = 0.0, delay: float = 0.0
) -> float:
    """``P(T > t)`` with an optional fixed network ``delay`` added to every response."""
    if setup_seconds > 0:
        return mmk_setup_response_sf(t - delay, lam, mu, k, setup_seconds)
    return mmk_response_sf(t - delay, lam, mu, k)


def mean_response_seconds(
    lam: float, mu: float, k: int, *, setup_seconds: float = 0.0, delay: float = 0.0
) -> float:
    if setup_seconds > 0:
        return delay + mmk_setup_mean_response_seconds(lam, mu, k, setup_seconds)
    return delay + mmk_mean_response_seconds(lam, mu, k)


def response_quantile_seconds(
    q: float, lam: float, mu: float, k: int, *, setup_seconds: float = 0.0, delay: float = 0.0
) -> float:
    """Smallest ``t`` with ``P(T > t) <= 1 - q`` (bisection; ``inf`` when unstable)."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"quantile must be in (0, 1), got {q}")
    if k == 0 or lam >= k * mu:
        return math.inf
    lo, hi = delay, delay + 1.0 / mu
    while response_sf(hi, lam, mu, k, setup_seconds=setup_seconds, delay=delay) > 1.0 - q:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if response_sf(mid, lam, mu, k, setup_seconds=setup_seconds, delay=delay) > 1.0 - q:
            lo = mid
        else:
            hi = mid
    return hi


def min_replicas_for_slo(
    lam: float,
    mu: float,
    slo_seconds: float,
    percentile: float,
    *,
    k_max: int = 1000,
    setup_seconds: float = 0.0,
    delay: float = 0.0,
) -> int | None:
    """Smallest ``k`` with ``P(T > slo) <= 1 - percentile``, or ``None`` if ``k_max`` is short.

    ``P(T > t)`` decreases in ``k``, so the first feasible ``k`` upward from the stability bound
    is the answer. An SLO tighter than the service time alone can allow is unreachable at any
    ``k`` and also returns ``None``.
    """
    _check(lam, mu, 1)
    if not 0.0 < percentile < 1.0:
        raise ValueError(f"percentile must be in (0, 1), got {percentile}")
    allowed = 1.0 - percentile
    if lam == 0:
        return 1 if response_sf(slo_seconds, 0.0, mu, 1, delay=delay) <= allowed else None
    # Even with no queueing, P(S > slo - delay) = exp(-mu (slo - delay)) must be small enough.
    if slo_seconds <= delay or math.exp(-mu * (slo_seconds - delay)) > allowed + 1e-12:
        return None
    k = max(1, math.floor(lam / mu) + 1)
    while k <= k_max:
        sf = response_sf(slo_seconds, lam, mu, k, setup_seconds=setup_seconds, delay=delay)
        if sf <= allowed:
            return k
        k += 1
    return None


def max_arrival_rate_for_slo(
    mu: float, k: int, slo_seconds: float, percentile: float, *, delay: float = 0.0
) -> float:
    """Largest ``lam`` at which ``k`` warm replicas keep ``P(T > slo) <= 1 - percentile``."""
    if k <= 0 or slo_seconds <= delay:
        return 0.0
    allowed = 1.0 - percentile
    if mmk_response_sf(slo_seconds - delay, 0.0, mu, k) > allowed:
        return 0.0
    lo, hi = 0.0, k * mu
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if mmk_response_sf(slo_seconds - delay, mid, mu, k) <= allowed:
            lo = mid
        else:
            hi = mid
    return lo


# --- admission: M/M/k/K -----------------------------------------------------------------------


def admission_capacity(k: int, mu: float, target_seconds: float, *, delay: float = 0.0) -> int:
    """Most requests a pool of ``k`` can hold while eq. 3 still meets ``target_seconds``.

    An arrival that finds ``n`` requests is admitted iff
    ``delay + max(0, n - k + 1)/(k mu) + 1/mu <= target``; this returns the smallest ``n`` that
    is refused, ``K`` (0 when even an idle replica is too slow, or ``k`` is 0).
    """
    slack = target_seconds - delay - 1.0 / mu
    if k <= 0 or slack < 0:
        return 0
    return k + math.floor(slack * k * mu + 1e-9)


def admission_reject_probability(
    lam: float, mu: float, k: int, target_seconds: float, *, delay: float = 0.0
) -> float:
    """Share of arrivals refused by admission: blocking probability of M/M/k/K (PASTA)."""
    _check(lam, mu, k)
    cap = admission_capacity(k, mu, target_seconds, delay=delay)
    if cap == 0:
        return 1.0
    if lam == 0:
        return 0.0
    a = lam / mu
    cap = min(cap, k + 20_000)  # beyond this the queue tail is numerically zero or unstable
    # log of the unnormalised stationary probabilities a^n/n! (n <= k), a^k/k! rho^(n-k) (n > k)
    n = np.arange(cap + 1)
    logp = np.where(
        n <= k,
        n * math.log(a) - gammaln(n + 1),
        k * math.log(a) - math.lgamma(k + 1) + (n - k) * math.log(a / k),
    )
    logp -= logp.max()
    p = np.exp(logp)
    return float(p[-1] / p.sum())


def min_replicas_for_admission(
    lam: float,
    mu: float,
    target_seconds: float,
    max_reject: float,
    *,
    k_max: int = 1000,
    delay: float = 0.0,
) -> int | None:
    """Smallest ``k`` whose admission refuses at most ``max_reject`` of the arrivals."""
    if not 0.0 < max_reject < 1.0:
        raise ValueError(f"max_reject must be in (0, 1), got {max_reject}")
    if admission_capacity(1, mu, target_seconds, delay=delay) == 0:
        return None
    if lam == 0:
        return 1
    k = max(1, math.floor(lam / mu * (1.0 - max_reject)))
    while k <= k_max:
        if admission_reject_probability(lam, mu, k, target_seconds, delay=delay) <= max_reject:
            return k
        k += 1
    return None


def reservation_blocking(
    lam_private: float, lam_normal: float, mu: float, k: int, capacity: int, normal_capacity: int
) -> tuple[float, float]:
    """(private, normal) refusal probabilities of a pool with trunk reservation.

    A private request is admitted while fewer than ``capacity`` requests are present
    (:func:`admission_capacity`), a normal one only while fewer than ``normal_capacity``: the
    places in between are kept for private traffic. Birth-death chain with birth
    ``lam_p + lam_n`` below ``normal_capacity`` and ``lam_p`` above, death ``min(n, k) mu``.
    """
    _check(lam_private + lam_normal, mu, k)
    if k == 0 or capacity == 0:
        return 1.0, 1.0
    capacity = min(capacity, k + 20_000)
    normal_capacity = min(max(normal_capacity, 0), capacity)
    logp = np.zeros(capacity + 1)
    for n in range(1, capacity + 1):
        birth = lam_private + lam_normal if n - 1 < normal_capacity else lam_private
        if birth <= 0:
            logp[n:] = -np.inf
            break
        logp[n] = logp[n - 1] + math.log(birth) - math.log(min(n, k) * mu)
    logp -= logp.max()
    p = np.exp(logp)
    p /= p.sum()
    return float(p[-1]), float(p[normal_capacity:].sum())
