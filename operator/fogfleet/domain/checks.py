"""The rules a fleet must meet before it can be built into a problem, one function per rule
that returns the value or the error: ``build_problem`` raises the first error it meets,
``fogfleet validate`` lists them all (``fleet_errors``), as ``references`` does for the
fleet's references."""

from __future__ import annotations

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.base import parse_cpu, parse_memory
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import ModuleRef, RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.errors import InvalidSpec

from .references import reference_errors, resolve_nodes

__all__ = ["capacity_of", "fleet_errors", "module_cycle", "node_capacity"]


def node_capacity(node: ComputeNode) -> tuple[float, float, float] | InvalidSpec:
    """The CPU cores, memory bytes and GPUs a node offers its modules (capacity less what is
    reserved), or why it offers none to plan with."""
    cap = node.spec.capacity
    if cap is None:
        return InvalidSpec(
            f"ComputeNode/{node.metadata.name}",
            "spec.capacity",
            "required when planning offline (the operator reads it from the Node)",
        )
    cpu = parse_cpu(cap.cpu) - parse_cpu(node.spec.reserved.cpu)
    mem = parse_memory(cap.memory) - parse_memory(node.spec.reserved.memory)
    if cpu <= 0:
        return InvalidSpec(
            f"ComputeNode/{node.metadata.name}",
            "spec.reserved.cpu",
            "reserves all of the node's CPU",
        )
    return cpu, max(mem, 0.0), float(cap.gpu)


def capacity_of(node: ComputeNode) -> tuple[float, float, float]:
    """``node_capacity``, raising its InvalidSpec (the problem build's: the checks ran first)."""
    got = node_capacity(node)
    if isinstance(got, InvalidSpec):
        raise got
    return got


def module_cycle(
    fleet: RobotFleet, k: int, ref: ModuleRef, mod: SoftwareModule
) -> float | InvalidSpec:
    """The cycle in seconds module ``mod`` (``spec.modules[k]``, ``ref``) has in this fleet:
    its override, else its own; or why it is not above zero."""
    ov = ref.overrides
    cycle = mod.spec.cycle_seconds if ov.cycle_seconds is None else ov.cycle_seconds
    if cycle <= 0:
        return InvalidSpec(
            f"RobotFleet/{fleet.metadata.name}",
            f"spec.modules[{k}].overrides.cycleTimeMillis",
            "must be greater than zero",
        )
    return cycle


def fleet_errors(fleet: RobotFleet, catalog: Catalog) -> list[InvalidSpec]:
    """Every error ``build_problem`` stops at the first of: each bad reference, each of the
    fleet's nodes with nothing to offer, each module whose cycle is not above zero."""
    errors = reference_errors(fleet, catalog)
    try:
        robots, others = resolve_nodes(fleet, catalog)
        nodes = robots + others
    except InvalidSpec as exc:  # a bad reference (listed) or a selector selecting no robot
        errors += [] if errors else [exc]
        named = [*fleet.spec.robots, *fleet.spec.nodes]
        nodes = [catalog.nodes[name] for name in named if name in catalog.nodes]
    errors += [got for node in nodes if isinstance(got := node_capacity(node), InvalidSpec)]
    namespace = fleet.metadata.namespace or "default"
    for k, ref in enumerate(fleet.spec.modules):
        mod = catalog.module(namespace, ref.name)
        cycle = None if mod is None else module_cycle(fleet, k, ref, mod)
        if isinstance(cycle, InvalidSpec):
            errors.append(cycle)
    return errors
