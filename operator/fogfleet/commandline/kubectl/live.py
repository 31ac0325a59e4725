"""A running fleet as the operator sees it: its objects read through a ``Source`` (the cluster
adapter, ``plugin.cluster``, or a fake) into a ``snapshot.FleetSnapshot`` with the room the
other fleets and pods hold on its nodes, and its problem built the one way
(``snapshot.problem_of``), with the deployed placement (``status.placement``, or the
Deployments' node affinity above 1000 instances) and the measured miss rates
(``status.measured``, else the SoftwareModules' ``status.observed``).

A what-if (``snapshot.WhatIf``) changes the snapshot before the build: a node removed, a robot
added, a link slowed."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.labels import ANNOTATION_NODE, LABEL_FLEET
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.robotfleet import RobotFleet, SchedulerName
from fogfleet.domain.problem import Problem
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import identity_of
from fogfleet.snapshot import (
    FleetSnapshot,
    Listed,
    WhatIf,
    held_by_others,
    problem_of,
    refused,
    snapshot_of,
    unavailable_in,
    with_what_if,
)
from fogfleet.snapshot.room import status_claims

__all__ = ["Live", "Source", "WhatIf", "read_fleet"]

Obj = dict[str, Any]
I64 = NDArray[np.int64]


class Source(Protocol):
    """What the plugin reads (``adapters.kube.KubeClient`` has these methods)."""

    def get_fleet(self, namespace: str, name: str) -> Obj | None: ...
    def list_fleets(self, namespace: str | None = None) -> list[Obj]: ...
    def list_modules(self, namespace: str | None) -> list[Obj]: ...
    def list_compute_nodes(self) -> list[Obj]: ...
    def list_nodes(self) -> list[Obj]: ...
    def list_deployments(self, namespace: str, selector: Mapping[str, str]) -> list[Obj]: ...
    def list_deployment_metadata(
        self, namespace: str, selector: Mapping[str, str]
    ) -> list[Obj]: ...
    def list_node_load(self, besides: tuple[str, str] | None = None) -> list[Obj]: ...


@dataclass(frozen=True)
class Live:
    """A running fleet's snapshot, its problem, its deployed placement."""

    snapshot: FleetSnapshot
    problem: Problem  # unavailable nodes masked out
    unavailable: dict[int, str]  # node index -> why
    placement: I64  # deployed (I,), -1 where unknown

    @property
    def fleet(self) -> RobotFleet:
        return self.snapshot.fleet

    @property
    def with_limits(self) -> bool:
        return self.fleet.spec.scheduler.algorithm is not SchedulerName.ONBOARD

    @property
    def measured(self) -> Mapping[str, float]:
        """Module -> measured miss rate."""
        return self.snapshot.measured

    @property
    def status(self) -> Obj:
        return dict(self.snapshot.status)

    def refused(self, i: int) -> dict[int, Any]:
        """Instance i's refusals by node (``domain.build.refusals``)."""
        return dict(refused(self.snapshot, self.problem, i))


def read_fleet(source: Source, namespace: str, name: str, what_if: WhatIf | None = None) -> Live:
    """The fleet ``namespace/name`` rebuilt as the operator builds it (see the docstring)."""
    raw = source.get_fleet(namespace, name)
    if raw is None:
        raise InvalidSpec(f"RobotFleet/{name}", "", f"not found in namespace {namespace}")
    listed = Listed(
        fleet=raw,
        compute_nodes=source.list_compute_nodes(),
        modules=source.list_modules(namespace),
        nodes=source.list_nodes(),
        deployments=_deployments(source, namespace, name),
    )
    claims = status_claims(source.list_fleets())
    load = source.list_node_load(besides=(namespace, label_value(name)))
    held = held_by_others((namespace, name), load, claims)
    snapshot = with_what_if(snapshot_of(listed, held), what_if)
    problem = problem_of(snapshot)
    return Live(
        snapshot=snapshot,
        problem=problem,
        unavailable=unavailable_in(snapshot, problem),
        placement=_deployed(problem, snapshot),
    )


def _deployments(source: Source, namespace: str, name: str) -> list[Obj]:
    """The fleet's Deployments as far as a plan reads them: their metadata alone when every
    one names its node (``fogfleet.io/node``, written by the operator beside the affinity),
    else whole (Deployments written before the annotation existed)."""
    selector = {LABEL_FLEET: label_value(name)}
    found = source.list_deployment_metadata(namespace, selector)
    if all(_names_its_node(d) for d in found):
        return found
    return source.list_deployments(namespace, selector)


def _names_its_node(deployment: Obj) -> bool:
    """A module's Deployment with its node annotation, or one that has none to give (an
    on-board standby, a k8s-default fleet's unbound Deployment)."""
    annotations = (deployment.get("metadata") or {}).get("annotations") or {}
    return ANNOTATION_NODE in annotations or identity_of(deployment) is None


def _deployed(problem: Problem, snapshot: FleetSnapshot) -> I64:
    """Where each instance runs (``FleetSnapshot.deployed``), by node index."""
    index: dict[str, int] = {}
    for j, nd in enumerate(problem.nodes):
        index.setdefault(nd.node_name, j)
        index.setdefault(nd.name, j)
    out = np.full(problem.n_instances, -1, dtype=np.int64)
    for i, inst in enumerate(problem.instances):
        node = snapshot.deployed.get((inst.robot, inst.module, inst.replica))
        if node is not None and node in index:
            out[i] = index[node]
    return out
