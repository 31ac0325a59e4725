"""The operator end to end on the local control plane: real kube-apiserver (CRD schemas, RBAC),
real kube-scheduler binding pods by the required node affinity we render, real controller
manager (Deployments, ReplicaSets, garbage collection), kwok nodes that can go NotReady.

Each test runs its own `fogfleet run` process scoped to the test's namespace.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    N_INSTANCES,
    ROOT,
    Operator,
    apply_warehouse,
    assert_pods_where_planned,
    condition_is,
    conditions,
    deployments,
    dump,
    events,
    fleet,
    wait_ready,
)
from e2e.portable.metrics import parse as parse_metrics
from fogfleet.render.wiring import is_ros_object

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("the bed's kwok warehouse nodes and the operator run as a host process"),
    pytest.mark.timeout(420),
]


# What an RBAC denial looks like in the operator's log: the apiserver's reason, kopf's
# APIForbiddenError, our DependencyUnavailable ("forbidden ...", "HTTP 403") or the client's
# "(403)". A bare " 403" is not one: "Planned ... in 403 ms" failed CI on 2026-11-30.
RBAC_DENIAL = re.compile(
    r"forbidden|HTTP 403\b|\(403\)|\b(?:code|status)\W{1,3}403\b", re.IGNORECASE
)


def test_warehouse_runs_where_planned_replans_once_and_cleans_up(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    t0 = time.monotonic()
    apply_warehouse(kube, namespace)
    wait_ready(kube, namespace)
    ready_s = time.monotonic() - t0
    pods = assert_pods_where_planned(kube, namespace)
    f = fleet(kube, namespace)
    assert f["status"]["observedGeneration"] == f["metadata"]["generation"]
    assert f["status"]["predictedMissRate"] is not None and f["status"]["planningMillis"] > 0
    assert len(events(kube, namespace, "Planned")) == 1
    table = kube.kubectl("get", "robotfleets", "-n", namespace).stdout
    assert "READY" in table and "True" in table and "40" in table, table
    print(
        f"\napply-to-Ready (40 pods, plan included): {ready_s:.1f}s; "
        f"planning {f['status']['planningMillis']} ms"
    )
    assert_usage_status(kube, namespace, f["status"]["placement"])

    # one module's cycle time changes: one re-plan, the other modules keep their pods
    before_uids = {name: pod["metadata"]["uid"] for name, pod in pods.items()}
    first_plan = f["status"].get("lastPlanTime")
    kube.kubectl(
        "patch",
        "softwaremodule",
        "arm-motion-generation",
        "-n",
        namespace,
        "--type=merge",
        "-p",
        '{"spec": {"cycleTimeMillis": 450}}',
    )
    # the second plan in the status (its Ready then says whether its rollout is done), not a
    # fixed sleep after its Event (generous: 60 s only guards a hang)
    kube.wait_for(
        "a second Planned event and the status of its plan",
        lambda: (
            len(events(kube, namespace, "Planned")) >= 2
            and fleet(kube, namespace)["status"].get("lastPlanTime") != first_plan
        ),
        60,
    )
    wait_ready(kube, namespace)
    time.sleep(3)  # an observation window: a burst would have made a third plan by now
    assert len(events(kube, namespace, "Planned")) == 2
    pods = assert_pods_where_planned(kube, namespace)
    status = fleet(kube, namespace)["status"]
    moved = {
        name
        for name, uid in before_uids.items()
        if pods.get(name, {}).get("metadata", {}).get("uid") != uid
    }
    untouched_modules = {n for n in moved if "arm-motion-generation" not in n}
    assert len(untouched_modules) <= status["migrations"], (moved, status["choiceReason"])
    print(f"re-plan: {len(moved)} pods replaced, migrations {status['migrations']}")
    assert parse_metrics(operator.metrics()).total("fogfleet_plans_total", fleet="warehouse") > 0

    # deleting the fleet removes every Deployment it owned
    kube.kubectl("delete", "robotfleet", "warehouse", "-n", namespace, "--wait=true", timeout=90)
    kube.wait_for("no Deployments left", lambda: not deployments(kube, namespace), 60)


def assert_usage_status(kube: Kube, namespace: str, placement: list[dict[str, Any]]) -> None:
    """SoftwareModules and ComputeNodes say which fleets place them and how many instances
    (the operator's usage pass, written through the real status subresource and CRD schema)."""
    per_module: dict[str, int] = {}
    for entry in placement:
        per_module[entry["module"]] = per_module.get(entry["module"], 0) + 1

    def modules_done() -> bool:
        mods = kube.kubectl_json("get", "softwaremodules", "-n", namespace)["items"]
        got = {m["metadata"]["name"]: (m.get("status") or {}) for m in mods}
        return all(
            got.get(name, {}).get("instances") == n
            and got[name].get("fleets") == ["warehouse"]
            and got[name].get("offloadable") in ("never", "candidate", "preferred")
            for name, n in per_module.items()
        )

    kube.wait_for("module usage status", modules_done, 60)
    node = placement[0]["node"]
    here = sum(e["node"] == node for e in placement)
    cn = kube.kubectl_json("get", "computenode", node)
    assert f"{namespace}/warehouse" in cn["status"]["fleets"], cn["status"]
    assert cn["status"]["instances"] >= here, cn["status"]
    assert conditions(cn)["Ready"]["status"] == "True", cn["status"]
    table = kube.kubectl("get", "softwaremodules", "-n", namespace).stdout
    assert "INSTANCES" in table and "SPLIT" in table, table
    explained = kube.kubectl("explain", "robotfleet.spec.scheduler.population").stdout
    assert "NSGA-II population size. Default: 100." in explained, explained


def test_a_not_ready_edge_node_is_left_and_the_fleet_recovers(
    kube: Kube, cluster: Cluster, namespace: str, operator: Operator
) -> None:
    apply_warehouse(kube, namespace)
    wait_ready(kube, namespace)
    placement = fleet(kube, namespace)["status"]["placement"]
    edge = sorted({p["node"] for p in placement if p["tier"] == "edge"})
    assert edge, dump(placement)
    node = edge[0]
    affected = {(p["robot"], p["module"]) for p in placement if p["node"] == node}
    kept = {(p["robot"], p["module"]): p["node"] for p in placement if p["node"] != node}
    try:
        cluster.set_node_not_ready(node)
        kube.wait_for(
            "Degraded or re-planned",
            lambda: (
                condition_is(kube, namespace, "Degraded", "True")
                or len(events(kube, namespace, "Migrated")) >= 1
            ),
            60,
            interval=0.5,
        )
        kube.wait_for(
            f"placement off {node}",
            lambda: all(p["node"] != node for p in fleet(kube, namespace)["status"]["placement"]),
            60,
        )
        wait_ready(kube, namespace)
        assert_pods_where_planned(kube, namespace)
        after = {
            (p["robot"], p["module"]): p["node"]
            for p in fleet(kube, namespace)["status"]["placement"]
        }
        assert all(after[k] != node for k in affected)
        stayed = sum(after[k] == n for k, n in kept.items())
        migrations = fleet(kube, namespace)["status"]["migrations"]
        # others move only to make room, and every move is reported
        assert len(kept) - stayed <= migrations
        print(f"\n{node} NotReady: {len(affected)} left it, {len(kept) - stayed} more moved")
        assert events(kube, namespace, "Migrated")
        assert condition_is(kube, namespace, "Degraded", "False")
    finally:
        cluster.set_node_not_ready(node, False)


def test_an_operator_killed_mid_reconcile_converges_after_restart(
    kube: Kube, namespace: str, operator: Operator
) -> None:
    apply_warehouse(kube, namespace)
    kube.wait_for(
        "the first Deployments", lambda: len(deployments(kube, namespace)) >= 1, 120, interval=0.2
    )
    operator.kill()
    partial = len(deployments(kube, namespace))
    operator.start().wait_live()
    wait_ready(kube, namespace)
    assert_pods_where_planned(kube, namespace)
    deps = deployments(kube, namespace)
    uid = fleet(kube, namespace)["metadata"]["uid"]
    assert len({d["metadata"]["name"] for d in deps}) == N_INSTANCES
    assert all(d["metadata"]["ownerReferences"][0]["uid"] == uid for d in deps)
    replicasets = kube.kubectl_json("get", "replicasets", "-n", namespace)["items"]
    live = [r for r in replicasets if r["spec"]["replicas"] > 0 and not is_ros_object(r)]
    assert len(live) == N_INSTANCES
    print(f"\nkilled after {partial} of {N_INSTANCES} Deployments; converged after restart")


def test_the_operator_works_under_the_charts_least_privilege_rbac(
    kube: Kube, namespace: str, crds: None, tmp_path: Path, diagnostics: list[Any]
) -> None:
    install = ROOT / "manifests" / "install"
    for name in (
        "00-namespace.yaml",
        "10-serviceaccount.yaml",
        "20-clusterrole.yaml",
        "21-clusterrolebinding.yaml",
    ):
        kube.kubectl("apply", "-f", str(install / name))
    token = kube.kubectl(
        "create", "token", "fogfleet-operator", "-n", "fogfleet-system", "--duration=1h"
    ).stdout.strip()
    config = kube.token_kubeconfig(token, tmp_path / "token.kubeconfig")
    denied = kube.kubectl("auth", "can-i", "delete", "nodes", kubeconfig=config, check=False)
    assert denied.stdout.strip() == "no"
    op = Operator(config, [namespace], tmp_path / "operator.log")
    diagnostics.append(lambda: ("operator log (token)", op.logs(150)))
    op.start().wait_live()
    try:
        apply_warehouse(kube, namespace)
        wait_ready(kube, namespace)
        assert_pods_where_planned(kube, namespace)
        denials = RBAC_DENIAL.findall(op.logs(100000))
        assert not denials, op.logs(60)
    finally:
        op.stop()
        # leave nothing cluster-wide behind (the Helm install test owns these names)
        for name in ("21-clusterrolebinding.yaml", "20-clusterrole.yaml", "10-serviceaccount.yaml"):
            kube.kubectl("delete", "-f", str(install / name), "--ignore-not-found", check=False)
