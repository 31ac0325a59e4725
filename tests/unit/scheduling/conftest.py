"""Tiny hand-built Problems for the scheduling tests, and a planner that proposes a given
placement."""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
import pytest

from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.robotfleet import SchedulerSettings
from fogfleet.bench.scheduling import warehouse_problem
from fogfleet.domain.problem import Allocation, Instance, NodeInfo, Problem
from fogfleet.scheduling.decision import CorePlanner
from fogfleet.scheduling.schedule import Schedule


class Fixed(CorePlanner):
    """A planner that proposes ``placement`` (the solver's figures for it; the decision's
    rules, such as the migration margin, judge it)."""

    def __init__(self, placement: list[int]) -> None:
        self.placement = placement

    def plan(self, problem: Problem, settings: SchedulerSettings) -> Schedule:
        real = CorePlanner().plan(problem, settings)
        return dataclasses.replace(real, placement=np.array(self.placement, dtype=np.int64))


def make_problem(
    *,
    tiers: list[int],
    cpu: list[float],
    mem: list[float],
    home: list[int],
    allowed: list[list[bool]],
    activation: list[float],
    cycle: list[float],
    request: list[list[float]],
    use: list[list[float]] | None = None,
    exe: list[list[float]],
    exe_std: list[list[float]] | None = None,
    net: list[list[float]] | None = None,
    memory: list[float] | None = None,
    traffic: list[float] | None = None,
    uplink: list[float] | None = None,
    power: list[list[float]] | None = None,
    cost: list[float] | None = None,
) -> Problem:
    n, i = len(tiers), len(home)
    tier_enum = {0: Tier.ROBOT, 1: Tier.EDGE, 2: Tier.CLOUD}
    al = np.array(allowed, dtype=bool)
    req = np.array(request, dtype=float)
    ex = np.where(al, np.array(exe, dtype=float), np.inf)
    sd = np.array(exe_std, dtype=float) if exe_std is not None else np.zeros((i, n))
    alloc = Allocation(
        req, np.array(use, dtype=float) if use is not None else req.copy(), ex, sd, use is None
    )
    return Problem(
        fleet="tiny",
        namespace="t",
        nodes=tuple(NodeInfo(f"n{j}", f"n{j}", tier_enum[t], "hw") for j, t in enumerate(tiers)),
        instances=tuple(
            Instance(f"n{h}" if h >= 0 else "", f"m{k}", 0) for k, h in enumerate(home)
        ),
        tier=np.array(tiers, dtype=np.int64),
        capacity=np.column_stack([cpu, mem, np.zeros(n)]).astype(float),
        cost=np.array(cost if cost is not None else [0.0] * n, dtype=float),
        power=np.array(power if power is not None else [[0.0] * 4] * n, dtype=float),
        uplink_bandwidth=np.array(uplink if uplink is not None else [1e8] * n, dtype=float),
        home=np.array(home, dtype=np.int64),
        allowed=al,
        activation=np.array(activation, dtype=float),
        cycle=np.array(cycle, dtype=float),
        memory=np.array(memory if memory is not None else [0.0] * i, dtype=float),
        gpu=np.zeros(i),
        net_mean=np.array(net, dtype=float) if net is not None else np.zeros((i, n)),
        net_std=np.zeros((i, n)),
        traffic=np.array(traffic if traffic is not None else [0.0] * i, dtype=float),
        limits=alloc,
        nominal=alloc,
        current=np.full(i, -1, dtype=np.int64),
    )


@pytest.fixture
def tiny() -> Problem:
    """One robot (node 0, 2 cores, 4 GB) and two edge nodes (4 cores, 8 GB each); three
    instances of the robot, the first pinned on board."""
    return make_problem(
        tiers=[0, 1, 1],
        cpu=[2.0, 4.0, 4.0],
        mem=[4.0, 8.0, 8.0],
        home=[0, 0, 0],
        allowed=[[True, False, False], [True, True, True], [True, True, True]],
        activation=[1.0, 0.5, 0.2],
        cycle=[0.1, 0.2, 1.0],
        request=[[1.0, 0, 0], [1.0, 2.0, 2.0], [1.0, 1.0, 1.0]],
        exe=[[0.05, 0, 0], [0.1, 0.1, 0.1], [0.5, 0.4, 0.4]],
        net=[[0.0, 0, 0], [0.0, 0.15, 0.15], [0.0, 0.1, 0.1]],
        memory=[1.0, 2.0, 1.0],
        traffic=[0.0, 40e6, 10e6],
        uplink=[50e6, 1e9, 1e9],
        power=[[100.0, 10.0, 5.0, 0.1], [0, 0, 0, 0], [0, 0, 0, 0]],
        cost=[0.0, 0.05, 0.04],
    )


@pytest.fixture
def edge_and_cloud() -> Problem:
    """Two edge nodes (1, 2) and two cloud nodes (3, 4) of 4 cores; two always-active
    instances of one core each that may run anywhere but the robot (node 0)."""
    return make_problem(
        tiers=[0, 1, 1, 2, 2],
        cpu=[2.0, 4.0, 4.0, 4.0, 4.0],
        mem=[4.0, 8.0, 8.0, 8.0, 8.0],
        home=[0, 0],
        allowed=[[False, True, True, True, True]] * 2,
        activation=[1.0, 1.0],
        cycle=[1.0, 1.0],
        request=[[1.0] * 5] * 2,
        exe=[[0.1] * 5] * 2,
    )


@lru_cache(maxsize=1)
def _warehouse() -> Problem:
    return warehouse_problem()


@pytest.fixture
def warehouse() -> Problem:
    return _warehouse()


class StepClock:
    """A clock that moves ``step`` seconds at every reading (a planning budget's tests)."""

    def __init__(self, step: float) -> None:
        self.now, self.step = 0.0, step

    def __call__(self) -> float:
        self.now += self.step
        return self.now


class GenerationClock:
    """A clock that only moves when NSGA-II finishes a generation (through ``progress``), by
    ``per_generation`` seconds: the budget cuts the search at the same generation on any
    machine, however fast or loaded."""

    def __init__(self, per_generation: float) -> None:
        self.now, self.per_generation = 0.0, per_generation

    def __call__(self) -> float:
        return self.now

    def tick(self, generation: int, total: int) -> None:
        self.now += self.per_generation
