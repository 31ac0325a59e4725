"""The operator installed in-cluster by its chart (two replicas electing a leader on a Lease,
from its image, on a real node), and reading who leads: shared by test_incluster.py and the
leader-failover fault test."""

from __future__ import annotations

import json
import secrets
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from datetime import datetime
from typing import Any

from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import CHART, OPERATOR_LABELS, helm, install_crds

__all__ = [
    "RELEASE",
    "SYSTEM",
    "installed",
    "kill_leader",
    "leader",
    "lease_time",
    "operator_pods",
    "running_pod_names",
]  # fmt: skip

RELEASE = "fogfleet"
SYSTEM = "fogfleet-system"


def operator_pods(kube: Kube, *, terminating: bool = False) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = kube.kubectl_json(
        "get", "pods", "-n", SYSTEM, "-l", OPERATOR_LABELS
    )["items"]
    return [p for p in items if terminating or not p["metadata"].get("deletionTimestamp")]


def leader(kube: Kube) -> str | None:
    proc = kube.kubectl(
        "get", "lease", "fogfleet-operator", "-n", SYSTEM, "-o", "json", check=False
    )
    if proc.returncode != 0:
        return None
    holder: str | None = json.loads(proc.stdout)["spec"].get("holderIdentity")
    return holder


def lease_time(
    kube: Kube, field: str, namespace: str = SYSTEM, name: str = "fogfleet-operator"
) -> float:
    """The Lease's ``spec.acquireTime`` or ``spec.renewTime`` as a Unix time: written by the
    holder itself (microseconds), so a takeover is timed by the operator's own writes, not
    by how fast a loaded machine lets the test notice it."""
    lease = kube.kubectl_json("get", "lease", name, "-n", namespace)
    return datetime.fromisoformat(lease["spec"][field]).timestamp()


def kill_leader(kube: Kube, bound_s: float) -> tuple[str, float]:
    """Delete the leader's pod with grace 0; returns the new leader and the failover time:
    from the delete to the new holder's ``acquireTime`` (the pods run on this machine's
    clock). The wait for it is longer than ``bound_s``: it only guards a hang, the caller
    asserts the failover time against its bound."""
    old = leader(kube)
    assert old in running_pod_names(kube), (old, running_pod_names(kube))
    killed = time.time()
    kube.kubectl("delete", "pod", old, "-n", SYSTEM, "--grace-period=0", "--force", "--wait=false")
    kube.wait_for(
        "another leader",
        lambda: leader(kube) not in (None, old) and leader(kube) in running_pod_names(kube),
        bound_s + 60,
        interval=0.5,
    )
    return str(leader(kube)), lease_time(kube, "acquireTime") - killed


def running_pod_names(kube: Kube) -> set[str]:
    return {
        p["metadata"]["name"] for p in operator_pods(kube) if p["status"].get("phase") == "Running"
    }


def _set(key: str, value: str | float) -> tuple[str, str]:
    """A value as helm takes it: ``--set`` reads 2.5 as a string, which the chart's schema
    refuses for a number, so numbers go through ``--set-json``."""
    if isinstance(value, str):
        return "--set", f"{key}={value}"
    return "--set-json", f"{key}={json.dumps(value)}"


@contextmanager
def installed(
    kube: Kube,
    prefix: str = "e2e-incluster",
    values: Mapping[str, str | float] | None = None,
    namespace: str | None = None,
) -> Iterator[str]:
    """The chart installed (release ``fogfleet`` in fogfleet-system, with ``values`` given as
    ``--set``, numbers as ``--set-json``) watching ``namespace`` (the caller's, left in place)
    or a fresh namespace, which it yields; uninstalled and the fresh namespace deleted
    afterwards."""
    install_crds(kube)
    # an interrupted earlier run may have left the plain-manifest install (not Helm's) behind
    for what in (
        ["clusterrolebinding", "fogfleet-operator"],
        ["clusterrole", "fogfleet-operator"],
        ["serviceaccount", "fogfleet-operator", "-n", SYSTEM],
    ):
        obj = kube.kubectl("get", *what, "-o", "json", check=False)
        if obj.returncode == 0 and "Helm" not in obj.stdout:
            kube.kubectl("delete", *what, check=False)
    # and an interrupted run of a suite may have left its release
    if RELEASE in helm("list", "-n", SYSTEM, "-q").split():
        helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
    ns = namespace or f"{prefix}-{secrets.token_hex(3)}"
    if namespace is None:
        kube.apply({"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": ns}})
    helm(
        "install", RELEASE, str(CHART), "-n", SYSTEM, "--create-namespace",
        "--set", f"watchNamespaces={{{ns}}}",
        # a real node (kwok would only pretend to run it); the chart already keeps it off robots
        "--set-string", "nodeSelector.fogfleet\\.io/e2e-real=true",
        "--set", "logFormat=plain",
        # the bed's CRDs come from crds/ (install_crds above, as every e2e test has them);
        # test_helm_crd_upgrade.py tests the chart's own CRD templates
        "--set", "crds.install=false",
        *[arg for key, value in (values or {}).items() for arg in _set(key, value)],
        "--wait", "--timeout", "240s",
    )  # fmt: skip
    try:
        yield ns
    finally:
        if RELEASE in helm("list", "-n", SYSTEM, "-q").split():
            helm("uninstall", RELEASE, "-n", SYSTEM, "--wait")
        if namespace is None:
            kube.kubectl("delete", "namespace", ns, "--wait=false", "--ignore-not-found",
                         check=False)  # fmt: skip
