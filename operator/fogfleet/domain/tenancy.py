"""Nodes shared with other tenants: what others hold on a node, and planning into what is left.

A site runs several fleets and other workloads on the same edge servers. A fleet plans into
each node's capacity minus what the others hold there: the CPU and memory the other fleets'
plans claim (or their pods request, where they run more than planned or follow no plan), and
the requests of every pod fogfleet does not own (DaemonSets, other teams' pods).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.base import format_millicores, parse_cpu, parse_memory
from fogfleet.api.v1alpha1.computenode import ComputeNode, NodeResources

from .problem import Problem

__all__ = ["Held", "claims_of", "with_held"]

MIN_CPU = 0.001  # a node others fill completely keeps 1m: nothing fits, and the plan says so


@dataclass(frozen=True)
class Held:
    """What others hold on one node: CPU cores, memory bytes, and who."""

    cpu: float = 0.0
    memory: float = 0.0
    holders: tuple[str, ...] = field(default=())
    shares: tuple[tuple[str, float], ...] = field(default=())
    """(holder, CPU cores) in the order the holders came: who holds how much."""

    def plus(self, cpu: float, memory: float, holder: str) -> Held:
        holders = self.holders if holder in self.holders else (*self.holders, holder)
        by = dict(self.shares)
        by[holder] = by.get(holder, 0.0) + cpu
        return Held(self.cpu + cpu, self.memory + memory, holders, tuple(by.items()))

    def describe(self) -> str:
        return f"{format_millicores(self.cpu)} CPU held by {', '.join(self.holders)}"

    def itemised(self) -> str:
        """Who holds how many cores: ``RobotFleet a/x 4 cores, pods in kube-system 0.5``."""
        parts = [f"{h} {round(c, 3):g}" for h, c in self.shares if c > 0]
        return (", ".join(parts) + " cores") if parts else "nobody"


def claims_of(
    problem: Problem, placement: NDArray[np.int64], with_limits: bool = True
) -> dict[str, tuple[float, float]]:
    """Kubernetes Node -> (CPU cores, memory bytes) a plan requests there."""
    alloc = problem.limits if with_limits else problem.nominal
    out: dict[str, tuple[float, float]] = {}
    for i, j in enumerate(placement):
        if j < 0:
            continue
        node = problem.nodes[int(j)].node_name
        cpu, mem = out.get(node, (0.0, 0.0))
        out[node] = (cpu + float(alloc.cpu_request[i, j]), mem + float(problem.memory[i]))
    return out


def with_held(node: ComputeNode, held: Held | None) -> ComputeNode:
    """The ComputeNode as the fleet may plan it: its capacity less what others hold (its
    reserve kept, and never less than 1m of CPU above it)."""
    cap = node.spec.capacity
    if held is None or cap is None or (held.cpu <= 0 and held.memory <= 0):
        return node
    reserved_cpu = parse_cpu(node.spec.reserved.cpu)
    cpu = max(parse_cpu(cap.cpu) - held.cpu, reserved_cpu + MIN_CPU)
    memory = max(parse_memory(cap.memory) - held.memory, parse_memory(node.spec.reserved.memory))
    left = NodeResources(cpu=format_millicores(cpu), memory=int(memory), gpu=cap.gpu)
    return node.model_copy(update={"spec": node.spec.model_copy(update={"capacity": left})})
