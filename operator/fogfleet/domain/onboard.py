"""What a module that cannot leave its robot needs there, from what it was measured doing
(issue 44; pure).

A fleet re-plans a drifting module with its learnt profile (``domain.observed``), and the plan
may move it to a node with room. A module whose gene space is its own robot alone (hard
real-time or safety-critical, III-B, or pinned there by its requirements) cannot move: the
re-plan can only give it more CPU on that robot, and when the robot has none to give, the
fleet must say that the robot is short for it, and by how much.

Its work per cycle is its measured execution time times the CPU limit it ran with (a
CPU-bound cycle takes as long as the kernel's quota makes it), so to finish within its cycle
time it needs::

    needed = t95 x cpu / cycle

with ``t95`` the 95th percentile of its measured execution times on the robot's hardware type
with that limit (a deadline is met by the slow cycles, not the mean). The most the robot can
guarantee it is its request there and the CPU the plan leaves unreserved on the robot (it may
burst above its request only while its neighbours idle); the robot is short by whatever
``needed`` exceeds that.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .observed import Observation
from .problem import Problem

__all__ = ["OnboardNeed", "cpu_needed", "onboard_needs", "pinned_on_board"]


@dataclass(frozen=True)
class OnboardNeed:
    """One robot's instance of a module that cannot leave it: what it needs there and what
    the robot can give it (cores; seconds)."""

    robot: str
    exec_time: float  # the 95th percentile of its measured execution times, seconds
    cycle: float  # its cycle time, seconds
    cpu: float  # the CPU limit it ran with, cores
    needed: float  # cores to finish within its cycle (module docstring)
    available: float  # its request there and the robot's unreserved CPU, cores

    @property
    def short(self) -> float:
        """Cores the robot lacks for it (0: the robot can give it what it needs)."""
        return max(0.0, self.needed - self.available)


def cpu_needed(exec_time: float, cpu: float, cycle: float) -> float:
    """Cores a CPU-bound cycle that took ``exec_time`` seconds under a ``cpu``-core limit
    needs to finish within ``cycle`` seconds."""
    return exec_time * cpu / cycle


def pinned_on_board(problem: Problem, i: int) -> bool:
    """Whether instance ``i`` may run on its own robot only (its gene space is its robot)."""
    home = int(problem.home[i])
    return home >= 0 and bool(problem.allowed[i, home]) and int(problem.allowed[i].sum()) == 1


def onboard_needs(
    problem: Problem,
    placement: NDArray[np.integer],
    module: str,
    observations: Iterable[Observation],
    unreserved: NDArray[np.float64],
) -> list[OnboardNeed]:
    """Per robot where ``module`` runs pinned on board under ``placement``, what it needs and
    what the robot can give it, the robot shortest of CPU first. ``observations``: the
    module's measured execution times (the one with the most samples on each hardware type
    counts; a type measured without a CPU limit has no need to tell); ``unreserved``: (N,)
    cores each node has left under the plan. Empty for a module that can move."""
    measured: dict[str, Observation] = {}
    for obs in observations:
        best = measured.get(obs.hardware_type)
        if obs.cpu is not None and obs.cpu > 0 and (best is None or obs.count > best.count):
            measured[obs.hardware_type] = obs
    out = []
    for i, inst in enumerate(problem.instances):
        j = int(placement[i])
        if inst.module != module or j != int(problem.home[i]) or not pinned_on_board(problem, i):
            continue
        seen = measured.get(problem.nodes[j].hardware_type)
        cycle = float(problem.cycle[i])
        if seen is None or seen.cpu is None or cycle <= 0:
            continue
        out.append(
            OnboardNeed(
                robot=problem.nodes[j].name,
                exec_time=seen.p95,
                cycle=cycle,
                cpu=seen.cpu,
                needed=cpu_needed(seen.p95, seen.cpu, cycle),
                available=float(problem.limits.cpu_request[i, j]) + max(0.0, float(unreserved[j])),
            )
        )
    return sorted(out, key=lambda n: (-n.short, -n.needed, n.robot))
