"""Thin kopf handlers. ``register`` wires them into a registry with the runtime's settings
(intervals come from Settings, so the decorators are applied here, not at import)."""

from __future__ import annotations

import kopf

from fogfleet import GROUP, VERSION
from fogfleet.api.labels import LABEL_MANAGED_BY, MANAGER
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.explanation import ExplanationRequest
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.settings import Settings

from . import lifecycle, related, robotfleet

__all__ = ["register"]

FLEETS = (GROUP, VERSION, RobotFleet.PLURAL)


def register(registry: kopf.OperatorRegistry, settings: Settings) -> kopf.OperatorRegistry:
    kopf.on.startup(registry=registry)(lifecycle.startup)
    kopf.on.login(registry=registry)(lifecycle.login)
    kopf.on.cleanup(registry=registry)(lifecycle.cleanup)
    for on in (kopf.on.create, kopf.on.update, kopf.on.resume):
        on(*FLEETS, registry=registry)(robotfleet.fleet_changed)
    # optional: no finalizer (owner references delete the Deployments without the operator);
    # the drift re-check and scaling are the runtime's own loops (lifecycle.startup), since
    # kopf timers would put a finalizer on every fleet and scaled module.
    kopf.on.delete(*FLEETS, registry=registry, optional=True)(robotfleet.fleet_deleted)
    # ... which kopf calls only while the object still exists (another finalizer holds it):
    # a fleet simply deleted is seen as its DELETED watch event
    kopf.on.event(*FLEETS, registry=registry)(robotfleet.fleet_event)
    kopf.on.event(GROUP, VERSION, ExplanationRequest.PLURAL, registry=registry)(
        related.explanation_event
    )
    if settings.watch_cache:
        return registry  # one watch per kind: the runtime's caches report the other kinds
    kopf.on.event(GROUP, VERSION, SoftwareModule.PLURAL, registry=registry)(related.module_event)
    kopf.on.event(GROUP, VERSION, ComputeNode.PLURAL, registry=registry)(related.compute_node_event)
    kopf.on.event("", "v1", "nodes", registry=registry)(related.node_event)
    kopf.on.event(
        "apps", "v1", "deployments", labels={LABEL_MANAGED_BY: MANAGER}, registry=registry
    )(related.deployment_event)
    return registry
