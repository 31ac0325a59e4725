"""The hub keeper (issue 47, item 5): a site gone long enough has its cloud instances scaled to
zero in their works, and given back when it returns; nothing is created or deleted."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from fogfleet.api.timestamps import timestamp
from fogfleet.controllers.keeper import Kept, gone_since, keep
from fogfleet.render.deployments import node_affinity
from fogfleet.render.manifestwork import ANNOTATION_PARKED, deployment_of, work_of

Obj = dict[str, Any]
T0 = 1_800_000_000.0  # the site's lease stopped (epoch seconds)


def _site(available: bool) -> Obj:
    status = "True" if available else "Unknown"
    cond = {"type": "ManagedClusterConditionAvailable", "status": status,
            "lastTransitionTime": timestamp(T0)}  # fmt: skip
    return {"metadata": {"name": "site-a"}, "status": {"conditions": [cond]}}


def _work(site: str, replicas: int = 2) -> Obj:
    dep = {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {"name": "w-mapping", "namespace": "warehouse",
                     "annotations": {"fogfleet.io/node": "cloud-1"}},
        "spec": {"replicas": replicas, "template": {"spec": {
            "affinity": node_affinity(["cloud-1"]), "containers": []}}},
    }  # fmt: skip
    return work_of(dep, "cloud", site)


class Hub:
    def __init__(self, site: Obj | None, works: list[Obj], merge: Any) -> None:
        self.site = site
        self.merge = merge
        self.works = {w["metadata"]["name"]: w for w in works}
        self.patches = 0

    def list_managed_clusters(self) -> list[Obj]:
        return [copy.deepcopy(self.site)] if self.site else []

    def list_all_works(self, selector: Mapping[str, str]) -> list[Obj]:
        return copy.deepcopy(list(self.works.values()))

    def patch_work(self, cluster: str, name: str, patch: Mapping[str, Any]) -> None:
        self.merge(self.works[name], patch)
        self.patches += 1


def _replicas(work: Obj) -> int:
    return int(work["spec"]["workload"]["manifests"][1]["spec"]["replicas"])


def test_a_site_gone_long_enough_is_parked_and_restored_when_it_returns(merge_patch: Any) -> None:
    hub = Hub(_site(available=False), [_work("site-a")], merge_patch)
    assert keep(hub, T0 + 599, gone_after=600) == Kept()  # not gone long enough yet
    assert keep(hub, T0 + 600, gone_after=600) == Kept(parked=1)
    work = next(iter(hub.works.values()))
    assert _replicas(work) == 0 and work["metadata"]["annotations"][ANNOTATION_PARKED] == "2"
    assert keep(hub, T0 + 700, gone_after=600) == Kept()  # parked once
    # the site's operator reads a parked instance as wanting 2 and not there (not Ready)
    view = deployment_of(work)
    assert view is not None and view["spec"]["replicas"] == 2
    hub.site = _site(available=True)
    assert keep(hub, T0 + 800, gone_after=600) == Kept(restored=1)
    work = next(iter(hub.works.values()))
    assert _replicas(work) == 2 and ANNOTATION_PARKED not in work["metadata"]["annotations"]
    assert keep(hub, T0 + 900, gone_after=600) == Kept() and hub.patches == 2


def test_only_the_gone_sites_works_are_parked_and_a_site_the_hub_forgot_is_gone(
    merge_patch: Any,
) -> None:
    hub = Hub(_site(available=False), [_work("site-a"), _work("site-b")], merge_patch)
    assert len(hub.works) == 2  # one name per site
    kept = keep(hub, T0 + 10_000, gone_after=600)
    assert kept == Kept(parked=2)  # site-b has no ManagedCluster: gone since always
    assert gone_since(None) == 0.0 and gone_since(_site(available=True)) is None
    assert gone_since(_site(available=False)) == T0
