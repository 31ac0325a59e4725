"""What a lost link leaves of each robot under a plan (issue 13): its offloaded modules with an
on-board fallback run on board, in the share the robot holds for them
(``Problem.fallback_reserve``); its other offloaded modules stop, so every cycle they would
have run counts as missed. The prediction uses the plan's own load model
(``Evaluation.instance_miss``) and the fleet's miss-rate definition: the mean over modules of
each module's share of missed cycles (here one instance per module and robot)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Allocation, Problem

from .evaluation import Evaluation

__all__ = ["CutRobot", "disconnected"]


@dataclass(frozen=True)
class CutRobot:
    robot: str
    reserved_cpu: float  # cores the robot holds for its fallbacks, whatever the plan
    standbys: tuple[str, ...]  # offloaded modules whose standby takes over
    stopped: tuple[str, ...]  # offloaded modules without a fallback: they stop
    miss_rate: float  # predicted while the link is down


def disconnected(problem: Problem, x: NDArray[np.integer]) -> list[CutRobot]:
    """Per robot with an offloaded module (in node order): what losing its link costs."""
    x = np.asarray(x, dtype=np.int64)
    home = problem.home
    held = problem.standing_by
    off = (home >= 0) & (x >= 0) & (x != home)
    local = np.where(off & held, home, x)  # the standbys take over on board
    cut = _standing_in(problem, off & held)
    ev = Evaluation(cut, local[None, :], _standby_allocation(cut, off & held, problem))
    miss = ev.instance_miss()[0]
    miss = np.where(off & ~held, 1.0, miss)
    reserve = problem.fallback_reserve(problem.limits)[:, 0]
    out: list[CutRobot] = []
    for r in np.flatnonzero(problem.tier == 0):
        mine = np.flatnonzero((home == r) & (x >= 0))
        if not off[mine].any():
            continue
        out.append(
            CutRobot(
                robot=problem.nodes[r].name,
                reserved_cpu=float(reserve[r]),
                standbys=tuple(problem.instances[i].module for i in mine if off[i] and held[i]),
                stopped=tuple(problem.instances[i].module for i in mine if off[i] and not held[i]),
                miss_rate=float(miss[mine].mean()),
            )
        )
    return out


def _standing_in(problem: Problem, standing_in: NDArray[np.bool_]) -> Problem:
    """The problem as the cut robot runs it: a variant standby at its own cycle time, its
    share of the reserve being what it runs with (as a standby of the module itself)."""
    if problem.fallback_variant is None:
        return problem
    cycle = problem.cycle
    if problem.fallback_cycle is not None:
        cycle = np.where(standing_in, problem.fallback_cycle, cycle)
    return dataclasses.replace(problem, cycle=cycle, fallback_variant=None)


def _standby_allocation(
    problem: Problem, standing_in: NDArray[np.bool_], planned: Problem
) -> Allocation:
    """The limits allocation with the standbys of ``standing_in`` on their home node running
    the row they were given (``Problem.fallback_row``: maybe less than the module's own; a
    variant's whatever the module's own at home, per ``planned``)."""
    lim = problem.limits
    rows = np.flatnonzero(standing_in)
    if problem.fallback_row is None or not rows.size:
        return lim
    h = problem.home[rows]
    fb = problem.fallback_row[rows]
    request, use = lim.cpu_request.copy(), lim.cpu_use.copy()
    mean, std = lim.exe_mean.copy(), lim.exe_std.copy()
    cpu = np.minimum(request[rows, h], fb[:, 0])
    if planned.fallback_variant is not None:
        cpu = np.where(planned.fallback_variant[rows], fb[:, 0], cpu)
    for a, v in zip((request, use, mean, std), (cpu, cpu, fb[:, 1], fb[:, 2]), strict=True):
        a[rows, h] = v
    return Allocation(request, use, mean, std, lim.has_limit)
