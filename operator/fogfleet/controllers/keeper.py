"""The hub keeper (issue 47, item 5): cloud instances stop costing money when their site is
gone, and come back when it returns. OCM has no such feature (its pull model keeps applied
work running while the hub or the site is away), so this is a small controller of ours that
runs beside the OCM hub (``fogfleet hub-keeper``; docs/multicluster.md).

A site is gone when its ManagedCluster has not been Available (its agent stopped renewing its
lease: the site lost power, or its WAN) for ``gone_after`` seconds. Then every ManifestWork
that site's operator wrote (label ``fogfleet.io/site``) is parked: its Deployment scaled to
zero in the work, its replicas kept in an annotation (``render.manifestwork.parked``), so the
cloud's agent scales it down and the work, the namespace and everything else stay. When the
site is Available again the keeper gives the works their replicas back. It never creates or
deletes a work: the site's operator owns what runs where.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from fogfleet.api.labels import LABEL_MANAGED_BY, LABEL_SITE, MANAGER
from fogfleet.api.timestamps import parse_timestamp
from fogfleet.render.manifestwork import parked, unparked
from fogfleet.snapshot.clusters import AVAILABLE

__all__ = ["KeeperPort", "Kept", "gone_since", "keep"]

log = logging.getLogger(__name__)
Obj = dict[str, Any]


class KeeperPort(Protocol):
    """What the keeper needs of the hub (adapters.hub.HubClient)."""

    def list_managed_clusters(self) -> list[Obj]: ...

    def list_all_works(self, selector: Mapping[str, str]) -> list[Obj]: ...

    def patch_work(self, cluster: str, name: str, patch: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class Kept:
    """What one pass did: works parked and works given their replicas back."""

    parked: int = 0
    restored: int = 0


def gone_since(managed: Mapping[str, Any] | None) -> float | None:
    """Since when (epoch seconds) a site's ManagedCluster has not been Available; None while it
    is. A site the hub does not know (any more) is gone since always (0)."""
    if managed is None:
        return 0.0
    conds = {c.get("type"): c for c in (managed.get("status") or {}).get("conditions") or []}
    available = conds.get(AVAILABLE)
    if available is not None and available.get("status") == "True":
        return None
    since = parse_timestamp((available or {}).get("lastTransitionTime"))
    return since if since is not None else 0.0


def keep(hub: KeeperPort, now: float, gone_after: float) -> Kept:
    """Park the works of every site gone for ``gone_after`` seconds or more, and give back
    their replicas to those of sites Available again."""
    clusters = {str(mc["metadata"]["name"]): mc for mc in hub.list_managed_clusters()}
    n_parked = n_restored = 0
    for work in hub.list_all_works({LABEL_MANAGED_BY: MANAGER}):
        meta = work.get("metadata") or {}
        site = (meta.get("labels") or {}).get(LABEL_SITE)
        if not site:
            continue
        since = gone_since(clusters.get(site))
        gone = since is not None and now - since >= gone_after
        patch = parked(work) if gone else unparked(work) if since is None else None
        if patch is None:
            continue
        cluster, name = str(meta["namespace"]), str(meta["name"])
        log.info("%s ManifestWork %s/%s: site %s is %s", "Parking" if gone else "Restoring",
                 cluster, name, site, "gone" if gone else "back")  # fmt: skip
        hub.patch_work(cluster, name, patch)
        n_parked += gone
        n_restored += not gone
    return Kept(n_parked, n_restored)
