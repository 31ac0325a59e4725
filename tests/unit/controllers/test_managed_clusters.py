"""A fleet with a ComputeNode that stands for an OCM ManagedCluster (issue 47): its instances
there become ManifestWorks on the hub, never Deployments at the site; it is Ready from the
works' feedback; a hub that does not answer disturbs nothing; the fleet's deletion takes its
works along."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from typing import Any

import pytest

from fogfleet.api.labels import LABEL_COMPONENT, LABEL_ROBOT
from fogfleet.api.timestamps import parse_timestamp
from fogfleet.contract.relay import ENV_RELAY_ROUTER
from fogfleet.controllers.deps import Deps, Hub
from fogfleet.controllers.fleet.clusters import ORPHAN_GRACE_SECONDS, delete_remote, sweep_orphans
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.controllers.measure.usage import reconcile_usage
from fogfleet.errors import DependencyUnavailable
from fogfleet.render.manifestwork import FEEDBACK
from fogfleet.render.relays import COMPONENT_RELAY, RELAY_CONTAINER
from fogfleet.render.wiring import is_ros_object
from fogfleet.snapshot.clusters import ROUTER_CLAIM

KEY = ("warehouse", "warehouse")
CLOUD = "cloud-1"  # the ComputeNode
CLUSTER = "cloud"  # the ManagedCluster it stands for
PRIVATE = "object-pose-estimation"  # given minPrivacy 1 here: the robots have 2, the cloud 0
Obj = dict[str, Any]


def _match(labels: Mapping[str, str], selector: Mapping[str, str]) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


class FakeHub:
    """An OCM hub in memory: ManagedClusters, and works its agents report on (``feed``)."""

    def __init__(self) -> None:
        self.clusters: dict[str, Obj] = {
            CLUSTER: {
                "metadata": {"name": CLUSTER},
                "spec": {"hubAcceptsClient": True},
                "status": {
                    "conditions": [
                        {
                            "type": "ManagedClusterConditionAvailable",
                            "status": "True",
                            "reason": "ManagedClusterAvailable",
                        }
                    ],
                    "allocatable": {"cpu": "64", "memory": "256Gi"},
                },
            }
        }
        self.works: dict[tuple[str, str], Obj] = {}
        self.applied: list[str] = []
        self.deleted: list[str] = []
        self.down = False

    def _up(self) -> None:
        if self.down:
            raise DependencyUnavailable("Cannot list the hub's ManagedClusters: timed out")

    def list_managed_clusters(self) -> list[Obj]:
        self._up()
        return copy.deepcopy(list(self.clusters.values()))

    def list_works(self, cluster: str, selector: Mapping[str, str]) -> list[Obj]:
        self._up()
        return copy.deepcopy(
            [
                w
                for (ns, _), w in self.works.items()
                if ns == cluster and _match(w["metadata"].get("labels") or {}, selector)
            ]
        )

    def apply_work(self, body: Obj) -> Obj:
        self._up()
        key = (body["metadata"]["namespace"], body["metadata"]["name"])
        stored = copy.deepcopy(body)
        stored["status"] = (self.works.get(key) or {}).get("status", {})
        self.works[key] = stored
        self.applied.append(key[1])
        return copy.deepcopy(stored)

    def delete_work(self, cluster: str, name: str) -> None:
        self._up()
        self.works.pop((cluster, name), None)
        self.deleted.append(name)

    def feed(self) -> None:
        """What each cluster's work agent reports: every Deployment rolled out."""
        for work in self.works.values():
            dep = next(
                m for m in work["spec"]["workload"]["manifests"] if m["kind"] == "Deployment"
            )
            values = {k: 1 for k in FEEDBACK}
            work["status"] = {
                "resourceStatus": {
                    "manifests": [
                        {
                            "resourceMeta": {"kind": "Deployment", "name": dep["metadata"]["name"]},
                            "statusFeedback": {
                                "values": [
                                    {"name": k, "fieldValue": {"type": "Integer", "integer": v}}
                                    for k, v in values.items()
                                ]
                            },
                        }
                    ]
                }
            }


@pytest.fixture
def hub() -> FakeHub:
    return FakeHub()


@pytest.fixture
def cloud_kube(kube: Any) -> Any:
    """The warehouse with its edge servers replaced by a cloud cluster, and one module whose
    data may not leave the site."""
    kube.add(
        {
            "apiVersion": "fogfleet.io/v1alpha1",
            "kind": "ComputeNode",
            "metadata": {"name": CLOUD},
            "spec": {
                "tier": "cloud",
                "hardwareType": "D16s_v3",
                "managedCluster": CLUSTER,
                "network": [{"type": "wan", "latencyMillis": 20, "bandwidthMbps": 50}],
            },
        }
    )
    kube.fleets[KEY]["spec"]["nodes"] = [CLOUD]
    kube.modules[("warehouse", PRIVATE)]["spec"].setdefault("requirements", {})["minPrivacy"] = 1
    return kube


@pytest.fixture
def cloud_deps(cloud_kube: Any, make_deps: Any, hub: FakeHub) -> Deps:
    deps: Deps = dataclasses.replace(make_deps(), hub=Hub(hub, "site-a"))
    return deps


def run(kube: Any, deps: Deps) -> Any:
    return reconcile(kube.get_fleet(*KEY), deps)


def _modules_of(hub: FakeHub) -> list[str]:
    return sorted(
        m["metadata"]["labels"]["fogfleet.io/module"]
        for w in hub.works.values()
        for m in w["spec"]["workload"]["manifests"]
        if m["kind"] == "Deployment"
    )


def test_instances_planned_into_the_cluster_become_works_and_never_site_deployments(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    out = run(cloud_kube, cloud_deps)
    placement = cloud_kube.fleets[KEY]["status"]["placement"]
    remote = sorted(p["module"] for p in placement if p["node"] == CLOUD)
    assert remote, "nothing planned into the cloud"
    assert _modules_of(hub) == remote
    assert PRIVATE not in remote
    site = [d for d in cloud_kube.deployments.values() if not is_ros_object(d)]
    assert len(site) + len(remote) == len(placement) and out.applied == len(placement)
    for work in hub.works.values():
        assert work["metadata"]["namespace"] == CLUSTER
        assert work["metadata"]["labels"]["fogfleet.io/site"] == "site-a"
        dep = work["spec"]["workload"]["manifests"][1]
        assert "ownerReferences" not in dep["metadata"]
        assert "nodeAffinity" not in (dep["spec"]["template"]["spec"].get("affinity") or {})


def test_the_fleet_is_ready_from_the_works_feedback_and_a_second_pass_writes_nothing(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    run(cloud_kube, cloud_deps)
    cloud_kube.run_pods()
    assert not run(cloud_kube, cloud_deps).ready  # the cloud's agent has not reported yet
    hub.feed()
    out = run(cloud_kube, cloud_deps)
    assert out.ready, cloud_kube.fleets[KEY]["status"]["conditions"]
    written = len(hub.applied)
    cloud_deps.full_reconcile_seconds = 0  # every pass a full one
    again = run(cloud_kube, cloud_deps)
    assert again.applied == again.pruned == 0 and len(hub.applied) == written


def test_a_hub_that_does_not_answer_strands_the_clusters_instances_and_deletes_nothing(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    run(cloud_kube, cloud_deps)
    cloud_kube.run_pods()
    hub.feed()
    run(cloud_kube, cloud_deps)
    works, site = dict(hub.works), dict(cloud_kube.deployments)
    hub.down = True
    cloud_deps.full_reconcile_seconds = 0
    run(cloud_kube, cloud_deps)  # does not raise
    assert hub.works == works and cloud_kube.deployments.keys() == site.keys()
    ready = {c["type"]: c for c in cloud_kube.fleets[KEY]["status"]["conditions"]}["Ready"]
    assert ready["status"] == "False", ready
    hub.down = False
    cloud_kube.run_pods()
    assert run(cloud_kube, cloud_deps).ready
    assert hub.works.keys() == works.keys()


def test_the_cluster_nodes_status_says_what_the_hub_says(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    reconcile_usage(cloud_deps)
    status = cloud_kube.compute_nodes[CLOUD]["status"]
    ready = {c["type"]: c for c in status["conditions"]}["Ready"]
    assert (ready["status"], ready["reason"]) == ("True", "ClusterAvailable")
    assert status["allocatableCpu"] == "64"
    hub.clusters[CLUSTER]["status"]["conditions"][0]["status"] = "Unknown"
    reconcile_usage(cloud_deps)
    ready = {c["type"]: c for c in cloud_kube.compute_nodes[CLOUD]["status"]["conditions"]}
    assert (ready["Ready"]["status"], ready["Ready"]["reason"]) == ("False", "ClusterUnavailable")


def test_without_a_hub_the_cluster_node_is_unavailable_and_nothing_is_placed_there(
    cloud_kube: Any, make_deps: Any
) -> None:
    cloud_kube.fleets[KEY]["spec"]["nodes"] = ["edge-1", "edge-2", CLOUD]
    deps = make_deps()
    run(cloud_kube, deps)
    placement = cloud_kube.fleets[KEY]["status"]["placement"]
    assert placement and CLOUD not in {p["node"] for p in placement}
    nodes = {c["type"]: c for c in cloud_kube.fleets[KEY]["status"]["conditions"]}
    assert nodes


def test_the_fleets_deletion_deletes_its_works_and_only_its(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    run(cloud_kube, cloud_deps)
    other = copy.deepcopy(next(iter(hub.works.values())))
    other["metadata"]["name"] = "another-sites-work"
    other["metadata"]["labels"]["fogfleet.io/site"] = "site-b"
    hub.works[(CLUSTER, "another-sites-work")] = other
    gone = delete_remote(cloud_deps, "warehouse", "warehouse")
    assert gone == len(hub.deleted) > 0
    assert list(hub.works) == [(CLUSTER, "another-sites-work")]


def test_works_of_a_fleet_deleted_while_the_operator_was_away_are_swept_once_old_enough(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    run(cloud_kube, cloud_deps)
    for work in hub.works.values():
        work["metadata"]["creationTimestamp"] = "2026-11-30T12:00:00Z"
    created = parse_timestamp("2026-11-30T12:00:00Z") or 0.0
    fleets = cloud_kube.list_fleets(None)
    assert sweep_orphans(cloud_deps, fleets, created + 3600) == 0  # its fleet is there
    assert sweep_orphans(cloud_deps, [], created + ORPHAN_GRACE_SECONDS / 2) == 0  # too young
    served = dataclasses.replace(cloud_deps.hub, namespaces=("elsewhere",))
    assert sweep_orphans(dataclasses.replace(cloud_deps, hub=served), [], created + 3600) == 0
    n = len(hub.works)
    assert sweep_orphans(cloud_deps, [], created + 3600) == n > 0 and not hub.works


def test_a_cluster_cut_off_keeps_its_instances_and_none_is_started_at_the_site_instead(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    """The cloud runs on while the site cannot see it (OCM's pull model): an instance there
    is stranded, not planned anew at the site, even with room there (no duplicate)."""
    cloud_kube.fleets[KEY]["spec"]["nodes"] = ["edge-1", "edge-2", CLOUD]
    cloud_kube.fleets[KEY]["metadata"]["generation"] = 2
    run(cloud_kube, cloud_deps)
    remote = set(_modules_of(hub))
    assert remote, "nothing planned into the cloud"
    cloud_kube.run_pods()
    hub.feed()
    run(cloud_kube, cloud_deps)
    works, site = dict(hub.works), set(cloud_kube.deployments)
    hub.down = True
    cloud_deps.full_reconcile_seconds = 0
    run(cloud_kube, cloud_deps)
    assert set(cloud_kube.deployments) == site, "a cloud instance was started at the site"
    assert hub.works == works
    hub.down = False
    cloud_kube.run_pods()
    assert run(cloud_kube, cloud_deps).ready
    assert set(_modules_of(hub)) == remote and set(cloud_kube.deployments) == site


def test_an_operator_restarted_during_a_cut_starts_no_cloud_instance_at_the_site(
    cloud_kube: Any, cloud_deps: Deps, make_deps: Any, hub: FakeHub
) -> None:
    """It has read neither the works nor the ManagedCluster: the fleet's status says where
    its instances run, and the ComputeNode's status what the cluster holds."""
    cloud_kube.fleets[KEY]["spec"]["nodes"] = ["edge-1", "edge-2", CLOUD]
    run(cloud_kube, cloud_deps)
    cloud_kube.run_pods()
    hub.feed()
    run(cloud_kube, cloud_deps)
    reconcile_usage(cloud_deps)  # the ComputeNode's status records the cluster's allocatable
    site = set(cloud_kube.deployments)
    hub.down = True
    restarted: Deps = dataclasses.replace(make_deps(), hub=Hub(hub, "site-a"))
    restarted.full_reconcile_seconds = 0
    run(cloud_kube, restarted)
    assert set(cloud_kube.deployments) == site, "a cloud instance was started at the site"


def test_the_cut_edges_get_relays_at_both_ends_and_lose_them_without_routers(
    cloud_kube: Any, cloud_deps: Deps, hub: FakeHub
) -> None:
    """With the site's router and the cloud's claimed one: every work's pod has a relay beside
    the module, each robot with an instance in the cloud a relay on its node; a second pass
    writes nothing; without the routers the relays go."""
    cloud_deps.hub = dataclasses.replace(cloud_deps.hub, router="tcp/198.18.0.1:7447")
    claim = {"name": ROUTER_CLAIM, "value": "tcp/10.96.0.20:7447"}
    hub.clusters[CLUSTER]["status"]["clusterClaims"] = [claim]
    run(cloud_kube, cloud_deps)
    assert hub.works
    robots = set()
    for work in hub.works.values():
        dep = work["spec"]["workload"]["manifests"][1]
        containers = dep["spec"]["template"]["spec"]["containers"]
        relay = {e["name"]: e["value"] for e in containers[-1]["env"]}
        assert containers[-1]["name"] == RELAY_CONTAINER
        assert relay[ENV_RELAY_ROUTER] == "tcp/10.96.0.20:7447"
        robots.add(dep["metadata"]["annotations"]["fogfleet.io/robot"])
    relays = {
        d["metadata"]["labels"][LABEL_ROBOT]: d
        for d in cloud_kube.deployments.values()
        if d["metadata"]["labels"].get(LABEL_COMPONENT) == COMPONENT_RELAY
    }
    assert set(relays) == robots - {""}
    assert ("warehouse", "warehouse-relay") in cloud_kube.network_policies
    cloud_deps.full_reconcile_seconds = 0
    applied = len(hub.applied)
    assert run(cloud_kube, cloud_deps).applied == 0 and len(hub.applied) == applied
    cloud_deps.hub = dataclasses.replace(cloud_deps.hub, router="")
    hub.clusters[CLUSTER]["status"]["clusterClaims"] = []
    run(cloud_kube, cloud_deps)
    for work in hub.works.values():
        containers = work["spec"]["workload"]["manifests"][1]["spec"]["template"]["spec"]
        assert RELAY_CONTAINER not in [c["name"] for c in containers["containers"]]
    assert not [
        d
        for d in cloud_kube.deployments.values()
        if d["metadata"]["labels"].get(LABEL_COMPONENT) == COMPONENT_RELAY
    ]
    assert ("warehouse", "warehouse-relay") not in cloud_kube.network_policies
