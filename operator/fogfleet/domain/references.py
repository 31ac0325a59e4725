"""A fleet's references to ComputeNodes and SoftwareModules, resolved against the catalogue: one
check per reference, which ``build_problem`` stops at and ``fogfleet validate`` runs on every
reference of every fleet."""

from __future__ import annotations

from fogfleet.api.loader import Catalog
from fogfleet.api.v1alpha1.common import LabelSelector, Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.robotfleet import ModuleRef, RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.errors import DanglingReference, InvalidSpec

__all__ = ["named_module", "reference_errors", "resolve_nodes"]


def _named_node(
    fleet: RobotFleet, catalog: Catalog, listed: str, k: int
) -> ComputeNode | InvalidSpec:
    """The ComputeNode ``spec.<listed>[k]`` names (robots: a robot; nodes: not one), or why
    not."""
    obj, at = f"RobotFleet/{fleet.metadata.name}", f"spec.{listed}[{k}]"
    name = getattr(fleet.spec, listed)[k]
    node = catalog.nodes.get(name)
    if node is None:
        return DanglingReference(obj, at, catalog.missing(f"ComputeNode {name!r}", name))
    robot = node.spec.tier is Tier.ROBOT
    if listed == "robots" and not robot:
        return InvalidSpec(
            obj, at, f"ComputeNode {name!r} is tier {node.spec.tier.value}, not robot"
        )
    if listed == "nodes" and robot:
        return InvalidSpec(obj, at, f"ComputeNode {name!r} is a robot; list it under robots")
    return node


def named_module(
    fleet: RobotFleet, catalog: Catalog, namespace: str, k: int, ref: ModuleRef
) -> SoftwareModule | InvalidSpec:
    """The SoftwareModule ``spec.modules[k]`` names in the fleet's namespace, or why not."""
    mod = catalog.module(namespace, ref.name)
    if mod is not None:
        return mod
    return DanglingReference(
        f"RobotFleet/{fleet.metadata.name}",
        f"spec.modules[{k}].name",
        catalog.missing(f"SoftwareModule {namespace}/{ref.name}", ref.name),
    )


def reference_errors(fleet: RobotFleet, catalog: Catalog) -> list[InvalidSpec]:
    """Every bad reference of ``fleet``: each robot, node and module it names that does not
    exist or is of the wrong tier."""
    checks: list[ComputeNode | SoftwareModule | InvalidSpec] = [
        _named_node(fleet, catalog, listed, k)
        for listed in ("robots", "nodes")
        for k in range(len(getattr(fleet.spec, listed)))
    ]
    namespace = fleet.metadata.namespace or "default"
    checks += [
        named_module(fleet, catalog, namespace, k, ref) for k, ref in enumerate(fleet.spec.modules)
    ]
    return [c for c in checks if isinstance(c, InvalidSpec)]


def resolve_nodes(
    fleet: RobotFleet, catalog: Catalog
) -> tuple[list[ComputeNode], list[ComputeNode]]:
    """The fleet's robots and its other nodes (named, then selected), or why not."""
    robots = [
        _raise_or(_named_node(fleet, catalog, "robots", k)) for k in range(len(fleet.spec.robots))
    ]
    robots += _selected(catalog, fleet.spec.robot_selector, robots, robot=True)
    if not robots:
        raise InvalidSpec(
            f"RobotFleet/{fleet.metadata.name}",
            "spec.robotSelector",
            "selects no robot ComputeNode",
        )
    others = [
        _raise_or(_named_node(fleet, catalog, "nodes", k)) for k in range(len(fleet.spec.nodes))
    ]
    others += _selected(catalog, fleet.spec.node_selector, others, robot=False)
    return robots, others


def _selected(
    catalog: Catalog, selector: LabelSelector | None, named: list[ComputeNode], *, robot: bool
) -> list[ComputeNode]:
    """The nodes of the tier (robots, or every other tier) that ``selector`` selects, by name,
    less those already ``named``."""
    if selector is None:
        return []
    return [
        node
        for node in sorted(catalog.nodes.values(), key=lambda n: n.metadata.name)
        if (node.spec.tier is Tier.ROBOT) is robot
        and selector.matches(node.metadata.labels)
        and node not in named
    ]


def _raise_or(got: ComputeNode | InvalidSpec) -> ComputeNode:
    if isinstance(got, InvalidSpec):
        raise got
    return got
