"""Task activation: when an instance is active (multi-robot-edge-cloud-scheduling IV-B, "GA-based
with TA"; Table II's avg. execution rate).

An instance alternates between *on* and *off* episodes. Both lengths are exponential, so the
on/off process is a two-state Markov chain; starting it in state *on* with probability
``activation`` makes it stationary from t = 0 (the residual of an exponential is exponential),
and the long-run active fraction is exactly ``activation``.

Episode length: a mobile-manipulation sub-task (drive to a shelf, plan an arm motion, look for
an object) lasts seconds to tens of seconds (Fig. 5 shows modules switching on and off over a
task period of a few minutes). The mean on-episode is ``activation * ACTIVE_PERIOD_S`` clipped to
[MIN_ACTIVE_S, MAX_ACTIVE_S]; the mean off-episode follows from the activation. Each instance
draws its episodes from its own random stream, so robots (and modules) are independent.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "ACTIVE_PERIOD_S",
    "MAX_ACTIVE_S",
    "MIN_ACTIVE_S",
    "Episodes",
    "active_time",
    "mean_episode_s",
    "sample_episodes",
]

ACTIVE_PERIOD_S = 40.0  # mean on + off before clipping the on part
MIN_ACTIVE_S = 10.0
MAX_ACTIVE_S = 30.0

# (starts, ends) of the on-episodes, sorted; the last end may lie beyond the horizon (or be inf)
Episodes = tuple[list[float], list[float]]


def mean_episode_s(activation: float) -> tuple[float, float]:
    """Mean (on, off) episode lengths in seconds for an activation fraction in (0, 1)."""
    on = min(max(activation * ACTIVE_PERIOD_S, MIN_ACTIVE_S), MAX_ACTIVE_S)
    return on, on * (1.0 - activation) / activation


def sample_episodes(activation: float, duration_s: float, rng: np.random.Generator) -> Episodes:
    """On-episodes covering [0, duration_s) of a stationary on/off process."""
    if activation >= 1.0:
        return [0.0], [math.inf]
    if activation <= 0.0:
        return [], []
    on, off = mean_episode_s(activation)
    starts: list[float] = []
    ends: list[float] = []
    t = 0.0
    active = bool(rng.random() < activation)
    while t < duration_s:
        length = float(rng.exponential(on if active else off))
        if active:
            starts.append(t)
            ends.append(t + length)
        t += length
        active = not active
    return starts, ends


def active_time(episodes: Episodes, duration_s: float) -> float:
    """Seconds of [0, duration_s) covered by the on-episodes."""
    starts, ends = episodes
    return sum(max(0.0, min(e, duration_s) - s) for s, e in zip(starts, ends, strict=True))
