"""A running fleet as the operator sees it: its objects read through a ``Source`` (the cluster
adapter, ``plugin.cluster``, or a fake) into a ``snapshot.FleetSnapshot`` with the room the
other fleets and pods hold on its nodes, and its problem built the one way
(``snapshot.problem_of``), with the deployed placement (``status.placement``, or its compact
form ``status.placementCompact`` above 1000 instances; the Deployments' node only for a fleet
whose status lists neither) and the measured miss rates
(``status.measured``, else the SoftwareModules' ``status.observed``).

A what-if (``snapshot.WhatIf``) changes the snapshot before the build: a node removed, a robot
added, a link slowed."""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.labels import ANNOTATION_NODE, LABEL_FLEET
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.placement import placement_entries_of
from fogfleet.errors import InvalidSpec
from fogfleet.render.deployments import identity_of
from fogfleet.snapshot import (
    Listed,
    WhatIf,
    held_by_others,
    problem_of,
    snapshot_of,
    unavailable_in,
    with_what_if,
)
from fogfleet.snapshot.live import Live, deployed_placement
from fogfleet.snapshot.room import status_claims

__all__ = ["Live", "Source", "WhatIf", "read_fleet"]

Obj = dict[str, Any]
I64 = NDArray[np.int64]
READERS = 5  # the reads read_fleet runs beside its own get of the fleet


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
    def ask_explanation(
        self, namespace: str, spec: Mapping[str, Any], seconds: float
    ) -> Obj | None: ...


def read_fleet(source: Source, namespace: str, name: str, what_if: WhatIf | None = None) -> Live:
    """The fleet ``namespace/name`` rebuilt as the operator builds it (see the docstring).

    The reads are independent, so they run side by side: the API server encodes one list while
    this process decodes another (at 1000 robots the Nodes and ComputeNodes are 8 MiB)."""
    with ThreadPoolExecutor(max_workers=READERS) as pool:
        compute_nodes = pool.submit(source.list_compute_nodes)
        modules = pool.submit(source.list_modules, namespace)
        nodes = pool.submit(source.list_nodes)
        fleets = pool.submit(source.list_fleets)
        load = pool.submit(source.list_node_load, besides=(namespace, label_value(name)))
        raw = source.get_fleet(namespace, name)
        if raw is None:
            raise InvalidSpec(f"RobotFleet/{name}", "", f"not found in namespace {namespace}")
        # the status's placement (its list, or its compact form) says where the instances
        # run: then the Deployments are not read (8000 of them at 1000 robots)
        deployments = (
            None
            if placement_entries_of(raw.get("status") or {})
            else _deployments(source, namespace, name)
        )
        listed = Listed(
            fleet=raw,
            compute_nodes=compute_nodes.result(),
            modules=modules.result(),
            nodes=nodes.result(),
            deployments=deployments,
        )
        held = held_by_others((namespace, name), load.result(), status_claims(fleets.result()))
    snapshot = with_what_if(snapshot_of(listed, held), what_if)
    problem = problem_of(snapshot)
    return Live(
        snapshot=snapshot,
        problem=problem,
        unavailable=unavailable_in(snapshot, problem),
        placement=deployed_placement(problem, snapshot),
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
