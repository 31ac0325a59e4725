"""Every label and annotation key fogfleet writes or reads, in one place.

Labels select (Services, NetworkPolicies, the operator's queries); annotations carry what a
reconcile must remember without a status field (which plan, which spec, the scaler's memory).
"""

from __future__ import annotations

__all__ = [
    "ANNOTATION_MANAGED_CLUSTER",
    "ANNOTATION_MODULE",
    "ANNOTATION_NODE",
    "ANNOTATION_PLAN",
    "ANNOTATION_REPLICA",
    "ANNOTATION_ROBOT",
    "ANNOTATION_ROLE",
    "ANNOTATION_SCALER_STATE",
    "ANNOTATION_SPEC_HASH",
    "COMPONENT_PROFILING",
    "DEDICATED_TAINT_KEY",
    "HOSTNAME_KEY",
    "LABEL_COMPONENT",
    "LABEL_FLEET",
    "LABEL_INSTANCE",
    "LABEL_MANAGED_BY",
    "LABEL_MODULE",
    "LABEL_PART_OF",
    "LABEL_PROFILE_CPU",
    "LABEL_PROFILE_HARDWARE",
    "LABEL_PROFILE_SPEC",
    "LABEL_ROBOT",
    "LABEL_SITE",
    "LABEL_SITE_NAMESPACE",
    "LABEL_TIER",
    "MANAGER",
    "ROLE_REMOTE",
    "ROLE_STANDBY",
]

MANAGER = "fogfleet"
"""Value of app.kubernetes.io/managed-by on everything the operator creates."""

LABEL_MANAGED_BY = "app.kubernetes.io/managed-by"
LABEL_PART_OF = "app.kubernetes.io/part-of"
LABEL_COMPONENT = "app.kubernetes.io/component"
LABEL_FLEET = "fogfleet.io/fleet"
DEDICATED_TAINT_KEY = "fogfleet.io/dedicated"
"""Taint key of nodes kept for the pods fogfleet plans (robot computers, fleet edge servers):
``kubectl taint node robot-1 fogfleet.io/dedicated=robot:NoSchedule`` keeps every other
workload, the operator included, off the node; every pod fogfleet renders tolerates it."""
LABEL_ROBOT = "fogfleet.io/robot"
LABEL_MODULE = "fogfleet.io/module"
LABEL_TIER = "fogfleet.io/tier"
"""On module pods (where the plan put them) and on Nodes (the tier a node belongs to)."""
LABEL_INSTANCE = "fogfleet.io/instance"
LABEL_PROFILE_HARDWARE = "fogfleet.io/profile-hardware-type"
LABEL_PROFILE_CPU = "fogfleet.io/profile-cpu"
LABEL_PROFILE_SPEC = "fogfleet.io/profile-spec"
"""On profiling Jobs (issue 10): the hardware type, CPU limit and module spec hash profiled."""
COMPONENT_PROFILING = "profiling"

ANNOTATION_ROBOT = "fogfleet.io/robot"
ANNOTATION_MODULE = "fogfleet.io/module"
ANNOTATION_REPLICA = "fogfleet.io/replica"
ANNOTATION_PLAN = "fogfleet.io/plan-id"
ANNOTATION_NODE = "fogfleet.io/node"
"""On a module's Deployment: the node its plan binds it to (its node affinity says the same),
so a reader of the Deployments' metadata alone knows the placement (``kubectl fogfleet`` on a
fleet too large for ``status.placement``). Not part of the spec hash."""
ANNOTATION_ROLE = "fogfleet.io/role"
"""On a module's on-board standby (its fallback, issue 13): ``standby``. Its Deployment is not
the instance's placement, so it has no identity (``render.deployments.identity_of``)."""
ROLE_STANDBY, ROLE_REMOTE = "standby", "remote"
"""Values of ``ANNOTATION_ROLE``: an offloaded instance with an on-board fallback (``remote``)
and its standby on the robot (``standby``, which its Deployment's name also says)."""
ANNOTATION_SPEC_HASH = "fogfleet.io/spec-hash"
ANNOTATION_MANAGED_CLUSTER = "fogfleet.io/managed-cluster"
"""On a ManifestWork the operator writes on an OCM hub (and the Deployment read back from it):
the managed cluster it runs in (render.manifestwork)."""
LABEL_SITE = "fogfleet.io/site"
"""On the ManifestWorks a site's operator writes on the hub: the site (FOGFLEET_CLUSTER_NAME),
so that several sites share one hub."""
LABEL_SITE_NAMESPACE = "fogfleet.io/namespace"
"""On those ManifestWorks: the site namespace of the fleet they belong to."""
ANNOTATION_SCALER_STATE = "fogfleet.io/scaler-state"

HOSTNAME_KEY = "kubernetes.io/hostname"
"""The well-known Node label node affinity pins a module to."""
