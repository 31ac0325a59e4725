"""A module's Deployment sent to a cluster of its own through Open Cluster Management: the
``ManifestWork`` the operator writes on the hub for an instance planned onto a ComputeNode
with ``spec.managedCluster`` (issue 47; docs/multicluster.md), and the Deployment the rest of
the operator reads back from it.

The operator holds no credentials of the cloud cluster: it writes one ManifestWork per
instance in the hub's namespace of that cluster, and the cluster's own work agent, which dials
out to the hub, applies it there. What the work carries (``work_of``):

* the fleet's namespace, created once and orphaned when the work goes (other works and other
  fleets of the namespace may still use it: ``SelectivelyOrphan``);
* the Deployment as rendered for the site, less what only means something at the site: its
  owner reference (the RobotFleet is not in that cluster: its garbage collector would delete
  the Deployment at once) and its node affinity (the cloud's own scheduler picks one of its
  machines); applied there with server-side apply;
* feedback rules that bring the Deployment's rollout back to the hub (JSONPaths: the
  generation it observed, replicas updated, ready and available), so that the fleet is Ready
  from OCM's feedback alone.

``deployment_of`` turns a work read from the hub back into the Deployment as the site would
hold it: the rendered object with its node affinity to the ComputeNode and a status made of
the feedback, so the planner's current placement, the stamp, the status and the apply engine
read a remote instance as they read a local one.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from fogfleet.api.labels import (
    ANNOTATION_MANAGED_CLUSTER,
    ANNOTATION_NODE,
    LABEL_FLEET,
    LABEL_MANAGED_BY,
    LABEL_SITE,
    LABEL_SITE_NAMESPACE,
    MANAGER,
)
from fogfleet.api.names import dns_label
from fogfleet.render.deployments import node_affinity
from fogfleet.render.names import work_name

__all__ = [
    "ANNOTATION_PARKED",
    "FEEDBACK",
    "WORK_API",
    "deployment_of",
    "managed_cluster_of",
    "parked",
    "unparked",
    "work_of",
    "work_selector",
]

Obj = dict[str, Any]
WORK_API = "work.open-cluster-management.io/v1"
# the cluster's field manager of what the work applies (OCM requires the work-agent prefix)
FIELD_MANAGER = f"work-agent-{MANAGER}"

# on a work the hub keeper parked (controllers.keeper): the replicas its Deployment had
ANNOTATION_PARKED = "fogfleet.io/parked-replicas"

# feedback name -> the Deployment's field it reports (OCM's JSONPaths rule): what the site's
# readiness check (controllers.status._deployment_done) reads
FEEDBACK: dict[str, str] = {
    "generation": ".metadata.generation",
    "observedGeneration": ".status.observedGeneration",
    "replicas": ".status.replicas",
    "updatedReplicas": ".status.updatedReplicas",
    "readyReplicas": ".status.readyReplicas",
    "availableReplicas": ".status.availableReplicas",
}


def work_selector(
    site: str, namespace: str | None = None, fleet_label: str | None = None
) -> dict[str, str]:
    """The labels of the works this site writes (for a namespace, and one fleet of it)."""
    labels = {LABEL_MANAGED_BY: MANAGER, LABEL_SITE: dns_label(site)}
    if namespace is not None:
        labels[LABEL_SITE_NAMESPACE] = namespace
    if fleet_label is not None:
        labels[LABEL_FLEET] = fleet_label
    return labels


def managed_cluster_of(deployment: Mapping[str, Any]) -> str | None:
    """The managed cluster a Deployment read back from a work runs in (None: at the site)."""
    ann = (deployment.get("metadata") or {}).get("annotations") or {}
    cluster = ann.get(ANNOTATION_MANAGED_CLUSTER)
    return str(cluster) if cluster else None


def _for_the_cluster(deployment: Obj) -> Obj:
    """The Deployment as the managed cluster gets it: no owner reference, no node affinity,
    no status."""
    out = copy.deepcopy(deployment)
    out.pop("status", None)
    meta = out["metadata"]
    for key in ("ownerReferences", "resourceVersion", "uid", "generation", "managedFields"):
        meta.pop(key, None)
    meta.get("annotations", {}).pop(ANNOTATION_MANAGED_CLUSTER, None)
    pod = out["spec"]["template"]["spec"]
    affinity = dict(pod.get("affinity") or {})
    affinity.pop("nodeAffinity", None)
    if affinity:
        pod["affinity"] = affinity
    else:
        pod.pop("affinity", None)
    return out


def work_of(deployment: Mapping[str, Any], cluster: str, site: str) -> Obj:
    """The ManifestWork, in the hub's namespace of ``cluster``, that runs ``deployment`` (a
    module's Deployment as rendered for the site, bound to one ComputeNode) in that cluster."""
    meta = deployment["metadata"]
    namespace, name = str(meta["namespace"]), str(meta["name"])
    labels = dict(meta.get("labels") or {})
    annotations = dict(meta.get("annotations") or {})
    sent = _for_the_cluster(dict(deployment))
    ns_manifest = {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": namespace}}
    deployment_id = {"group": "apps", "resource": "deployments", "name": name}
    namespace_id = {"group": "", "resource": "namespaces", "name": namespace}
    return {
        "apiVersion": WORK_API,
        "kind": "ManifestWork",
        "metadata": {
            "name": work_name(site, namespace, name),
            "namespace": cluster,
            "labels": {
                **work_selector(site, namespace, labels.get(LABEL_FLEET)),
                **{k: v for k, v in labels.items() if k.startswith("fogfleet.io/")},
            },
            "annotations": {**annotations, ANNOTATION_MANAGED_CLUSTER: cluster},
        },
        "spec": {
            "workload": {"manifests": [ns_manifest, sent]},
            "deleteOption": {
                "propagationPolicy": "SelectivelyOrphan",
                "selectivelyOrphans": {"orphaningRules": [namespace_id]},
            },
            "manifestConfigs": [
                {
                    "resourceIdentifier": namespace_id,
                    "updateStrategy": {"type": "CreateOnly"},
                },
                {
                    "resourceIdentifier": {**deployment_id, "namespace": namespace},
                    "updateStrategy": {
                        "type": "ServerSideApply",
                        "serverSideApply": {"force": True, "fieldManager": FIELD_MANAGER},
                    },
                    "feedbackRules": [
                        {
                            "type": "JSONPaths",
                            "jsonPaths": [{"name": k, "path": p} for k, p in FEEDBACK.items()],
                        }
                    ],
                },
            ],
        },
    }


def _manifests(work: Mapping[str, Any]) -> list[Obj]:
    found: list[Obj] = ((work.get("spec") or {}).get("workload") or {}).get("manifests") or []
    return found


def _deployment(manifests: list[Obj]) -> Obj | None:
    """The Deployment among a work's manifests (ours carry one)."""
    return next((m for m in manifests if m.get("kind") == "Deployment"), None)


def _feedback(work: Mapping[str, Any], name: str) -> dict[str, int]:
    """The Deployment ``name``'s fed-back values (integers) in the work's status."""
    manifests = ((work.get("status") or {}).get("resourceStatus") or {}).get("manifests") or []
    for entry in manifests:
        meta = entry.get("resourceMeta") or {}
        if meta.get("kind") != "Deployment" or meta.get("name") != name:
            continue
        out: dict[str, int] = {}
        for value in (entry.get("statusFeedback") or {}).get("values") or []:
            field = value.get("fieldValue") or {}
            if value.get("name") in FEEDBACK and field.get("type") == "Integer":
                out[str(value["name"])] = int(field.get("integer") or 0)
        return out
    return {}


def deployment_of(work: Mapping[str, Any]) -> Obj | None:
    """The Deployment a work of ours carries, as the site would hold it: bound to its
    ComputeNode, its status what the cluster's agent fed back (None: not one of ours)."""
    sent = _deployment(_manifests(work))
    work_meta = work.get("metadata") or {}
    annotations = dict(work_meta.get("annotations") or {})
    node = annotations.get(ANNOTATION_NODE)
    if sent is None or not node:
        return None
    dep: Obj = copy.deepcopy(sent)
    meta = dep["metadata"]
    meta["annotations"] = {**(meta.get("annotations") or {}), **annotations}
    if work_meta.get("deletionTimestamp"):
        meta["deletionTimestamp"] = work_meta["deletionTimestamp"]
    pod = dep["spec"]["template"]["spec"]
    pod["affinity"] = {**(pod.get("affinity") or {}), **node_affinity([str(node)])}
    if ANNOTATION_PARKED in annotations:  # parked: it wants what it had, and is not there
        dep["spec"]["replicas"] = int(annotations[ANNOTATION_PARKED])
    fed = _feedback(work, str(meta["name"]))
    meta["generation"] = fed.pop("generation", 0)
    dep["status"] = fed
    return dep


def _with_replicas(work: Mapping[str, Any], replicas: int) -> list[Obj]:
    manifests = copy.deepcopy(_manifests(work))
    dep = _deployment(manifests)
    if dep is not None:
        dep.setdefault("spec", {})["replicas"] = replicas
    return manifests


def _replicas(work: Mapping[str, Any]) -> int:
    dep = _deployment(_manifests(work)) or {}
    return int((dep.get("spec") or {}).get("replicas", 1))


def parked(work: Mapping[str, Any]) -> Obj | None:
    """The merge patch that scales a work's Deployment to zero and remembers its replicas
    (None: already parked)."""
    annotations = (work.get("metadata") or {}).get("annotations") or {}
    if ANNOTATION_PARKED in annotations:
        return None
    return {
        "metadata": {"annotations": {ANNOTATION_PARKED: str(_replicas(work))}},
        "spec": {"workload": {"manifests": _with_replicas(work, 0)}},
    }


def unparked(work: Mapping[str, Any]) -> Obj | None:
    """The merge patch that gives a parked work's Deployment its replicas back (None: not
    parked)."""
    annotations = (work.get("metadata") or {}).get("annotations") or {}
    if ANNOTATION_PARKED not in annotations:
        return None
    replicas = int(annotations[ANNOTATION_PARKED])
    return {
        "metadata": {"annotations": {ANNOTATION_PARKED: None}},
        "spec": {"workload": {"manifests": _with_replicas(work, replicas)}},
    }
