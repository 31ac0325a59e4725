"""Fleet simulator: runs a plan over a horizon and measures missed cycle times.

Reference implementation of the shared execution model (team brief; multi-robot-edge-cloud-
scheduling III-D eq. 4-6 and IV): an instance is active in on/off episodes (``episodes``); while
active it runs cycles t_cycle = t_in + t_exe + t_out (eq. 4) and misses when t_cycle exceeds its
expected cycle time (the tau > 1 of eq. 5, counted like IV: any excess is a miss); executions on
a node share its CPU by processor sharing with cpu_use as the cap, weighted by the CPU
requests as CFS weighs pods (``engine``).

Random draws (numpy Generators derived from the seed only): each instance has its own streams
(episodes; execution and transfer noise), drawn independently of the placement, so plans
compared with the same seed see the same activity and the same noise quantiles (common random
numbers: differences between plans are not sampling noise).

- execution time of a cycle: lognormal with mean exe_mean[i, j] and std exe_std[i, j] (positive,
  right-skewed like measured run times; exactly exe_mean when the std is 0), at cpu_use[i, j]
  cores, slowed down under contention;
- transfer: max(0, N(net_mean[i, j], net_std[i, j])), half before and half after execution.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Allocation, Problem

from .engine import Track, run_independent, run_shared
from .episodes import Episodes, active_time, sample_episodes
from .result import SimResult

__all__ = ["fleet_miss_rate", "simulate"]


def _lognormal(mean: float, std: float, z: NDArray[np.float64]) -> list[float]:
    """Execution times with the given mean and std from standard normal draws ``z``."""
    if std <= 0.0 or mean <= 0.0:
        return [max(mean, 0.0)] * len(z)
    sigma2 = math.log1p((std / mean) ** 2)
    mu = math.log(mean) - sigma2 / 2.0
    out: list[float] = np.exp(mu + math.sqrt(sigma2) * z).tolist()
    return out


def _shift_first(episodes: Episodes, phase: float) -> Episodes:
    """Start the first cycle of an episode already under way at t = 0 at ``phase``."""
    starts, ends = episodes
    if not starts or starts[0] > 0.0:
        return episodes
    if phase >= ends[0]:
        return starts[1:], ends[1:]
    return [phase, *starts[1:]], ends


def _check(problem: Problem, placement: NDArray[np.int64], allocation: Allocation) -> None:
    n_i, n_n = problem.n_instances, problem.n_nodes
    if placement.shape != (n_i,):
        raise ValueError(f"placement has shape {placement.shape}, expected ({n_i},)")
    if np.any(problem.cycle[placement >= 0] <= 0.0):
        raise ValueError("cycle times must be positive")
    if np.any((placement < -1) | (placement >= n_n)):
        raise ValueError(f"placement values must lie in [-1, {n_n})")
    for i, j in enumerate(placement.tolist()):
        if j < 0:
            continue
        mean = float(allocation.exe_mean[i, j])
        if not math.isfinite(mean) or allocation.cpu_use[i, j] <= 0.0:
            raise ValueError(
                f"{problem.label(i)} cannot run on {problem.nodes[j].name}: no execution profile "
                "there (its module may not use the node)"
            )


def simulate(
    problem: Problem,
    placement: NDArray[np.int64],
    allocation: Allocation,
    duration_s: float = 120.0,
    seed: int = 0,
    *,
    all_active: bool = False,
    aligned_start: bool = False,
    spread: float = 0.0,
) -> SimResult:
    """Simulate ``placement`` (node index per instance, -1 = not run) under ``allocation``.

    ``all_active`` ignores the activation rates and keeps every instance active all the time:
    the paper's runs without task allocation (IV-B: "K8s default", "GA-based", "GA-based with
    limits" activate all modules in parallel; only "GA-based with TA" uses the rates).

    An instance already active at t = 0 has been running before the horizon, so the phase of
    its cycles is uniform: its first cycle starts at U(0, cycle) (otherwise all instances with
    the same period would run in lockstep). ``aligned_start`` starts them all at 0 instead, for
    hand-checkable runs. ``spread`` is the share of a short node's CPU that goes to the job
    that began executing last (``engine``: how the kernel spreads a shortage; 0, processor sharing
    alone, is the declared model). Deterministic per ``seed``. Raises ValueError for a
    malformed plan or one that puts an instance where it has no execution profile.
    """
    if not duration_s > 0.0:
        raise ValueError("duration_s must be positive")
    if not 0.0 <= spread <= 1.0:
        raise ValueError(f"spread must lie in [0, 1], got {spread}")
    placement = np.array(placement, dtype=np.int64)  # own copy: it is frozen into the result
    _check(problem, placement, allocation)
    n_i, n_n = problem.n_instances, problem.n_nodes
    streams = np.random.SeedSequence(seed).spawn(n_i)

    tracks: dict[int, Track] = {}
    active = np.full(n_i, np.nan)
    for i, j in enumerate(placement.tolist()):
        if j < 0:
            continue
        ep_seq, noise_seq = streams[i].spawn(2)
        cycle = float(problem.cycle[i])
        ep_rng = np.random.default_rng(ep_seq)
        rate = 1.0 if all_active else float(problem.activation[i])
        episodes = sample_episodes(rate, duration_s, ep_rng)
        active[i] = active_time(episodes, duration_s) / duration_s
        noise = np.random.default_rng(noise_seq)
        phase = float(noise.random()) * cycle
        if not aligned_start:
            episodes = _shift_first(episodes, phase)
        n_max = int(duration_s // cycle) + 2  # cycle starts are >= cycle apart
        z = noise.standard_normal(n_max)
        z_net = noise.standard_normal(n_max)
        net = np.maximum(problem.net_mean[i, j] + problem.net_std[i, j] * z_net, 0.0) / 2.0
        half: list[float] = net.tolist()
        tracks[i] = Track(
            cycle=cycle,
            demand=float(allocation.cpu_use[i, j]),
            work=_lognormal(float(allocation.exe_mean[i, j]), float(allocation.exe_std[i, j]), z),
            d_in=half,
            d_out=half,
            episodes=episodes,
            horizon=duration_s,
            weight=float(allocation.cpu_request[i, j]),
        )

    busy = np.zeros(n_n)
    for j in range(n_n):
        on_node = [i for i in tracks if placement[i] == j]
        cap = float(problem.capacity[j, 0])
        demand = sum(tracks[i].demand for i in on_node if tracks[i].episodes[0])
        if demand <= cap * (1 + 1e-9):
            busy[j] = sum(run_independent(tracks[i]) for i in on_node)
        else:
            busy[j] = run_shared([tracks[i] for i in on_node], cap, duration_s, spread)

    return _summarise(problem, placement, tracks, active, busy, duration_s, seed)


def _rate(missed: int, cycles: int) -> float:
    return missed / cycles if cycles else math.nan


def _summarise(
    problem: Problem,
    placement: NDArray[np.int64],
    tracks: dict[int, Track],
    active: NDArray[np.float64],
    busy: NDArray[np.float64],
    duration_s: float,
    seed: int,
) -> SimResult:
    n_i = problem.n_instances
    cycles = np.zeros(n_i, dtype=np.int64)
    missed = np.zeros(n_i, dtype=np.int64)
    for i, tr in tracks.items():
        cycles[i] = len(tr.durations)
        missed[i] = tr.missed
    modules = tuple(inst.module for inst in problem.instances)
    names = list(dict.fromkeys(modules))
    mod_rate: dict[str, float] = {}
    mod_cycles: dict[str, int] = {}
    mod_p95: dict[str, float] = {}
    for m in names:
        idx = [i for i in range(n_i) if modules[i] == m]
        c, x = int(cycles[idx].sum()), int(missed[idx].sum())
        durations = [d for i in idx if i in tracks for d in tracks[i].durations]
        mod_rate[m] = _rate(x, c)
        mod_cycles[m] = c
        mod_p95[m] = float(np.percentile(durations, 95)) if durations else math.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        inst_rate = np.where(cycles > 0, missed / np.maximum(cycles, 1), np.nan)
    capacity = problem.capacity[:, 0] * duration_s
    util = np.divide(busy, capacity, out=np.zeros_like(busy), where=capacity > 0)
    for a in (placement, cycles, missed, inst_rate, active, util):
        a.setflags(write=False)
    total, total_missed = int(cycles.sum()), int(missed.sum())
    return SimResult(
        duration_s=float(duration_s),
        seed=int(seed),
        cycles=total,
        missed=total_missed,
        miss_rate=fleet_miss_rate(mod_rate),
        module_miss_rate=mod_rate,
        module_cycles=mod_cycles,
        module_p95_cycle_s=mod_p95,
        instance_labels=tuple(problem.label(i) for i in range(n_i)),
        instance_modules=modules,
        node_names=tuple(nd.name for nd in problem.nodes),
        placement=placement,
        instance_cycles=cycles,
        instance_missed=missed,
        instance_miss_rate=inst_rate,
        active_fraction=active,
        node_utilisation=util,
        unplaced=tuple(int(i) for i in np.flatnonzero(placement < 0)),
    )


def fleet_miss_rate(module_rates: dict[str, float]) -> float:
    """The fleet's figure from its modules' rates: their mean over the modules that ran a
    cycle (NaN if none did), as the planner's ``missRate`` (``Evaluation.miss_rate``)."""
    rates = [r for r in module_rates.values() if not math.isnan(r)]
    return float(np.mean(rates)) if rates else math.nan
