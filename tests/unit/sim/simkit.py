"""Tiny hand-built Problems for the simulator's tests (imported by them; not a test module)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fogfleet.api.v1alpha1.common import Tier
from fogfleet.domain.problem import Allocation, Instance, NodeInfo, Problem


@dataclass(frozen=True)
class Job:
    """One instance, on every node the same figures (std 0, no transfer unless given)."""

    module: str
    exe: float
    cpu: float
    cycle: float
    activation: float = 1.0
    std: float = 0.0
    net: float = 0.0
    net_std: float = 0.0
    robot: str = "r1"


def build(cores: Sequence[float], jobs: Sequence[Job]) -> Problem:
    n, i = len(cores), len(jobs)

    def full(values: Sequence[float]) -> np.ndarray:
        return np.repeat(np.asarray(values, dtype=np.float64)[:, None], n, axis=1)

    alloc = Allocation(
        cpu_request=full([j.cpu for j in jobs]),
        cpu_use=full([j.cpu for j in jobs]),
        exe_mean=full([j.exe for j in jobs]),
        exe_std=full([j.std for j in jobs]),
        has_limit=True,
    )
    return Problem(
        fleet="tiny",
        namespace="default",
        nodes=tuple(NodeInfo(f"n{k}", f"n{k}", Tier.EDGE, "default") for k in range(n)),
        instances=tuple(Instance(j.robot, j.module, 0) for j in jobs),
        tier=np.ones(n, dtype=np.int64),
        capacity=np.array([[c, 64e9, 0.0] for c in cores]),
        cost=np.zeros(n),
        power=np.zeros((n, 4)),
        uplink_bandwidth=np.full(n, 1e9),
        home=np.full(i, -1, dtype=np.int64),
        allowed=np.ones((i, n), dtype=bool),
        activation=np.array([j.activation for j in jobs]),
        cycle=np.array([j.cycle for j in jobs]),
        memory=np.zeros(i),
        gpu=np.zeros(i),
        net_mean=full([j.net for j in jobs]),
        net_std=full([j.net_std for j in jobs]),
        traffic=np.zeros(i),
        limits=alloc,
        nominal=alloc,
        current=np.full(i, -1, dtype=np.int64),
    )
