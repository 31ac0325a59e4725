"""kube-apiserver and etcd restarted together while a fleet rolls out (issue 37, item 3).

A ROS 2 fleet runs on the real nodes (its workloads count messages and cycles); the operator
runs as a host process. The warehouse (40 instances on kwok's nodes) is applied, and as soon
as the operator has planned it and begun creating its Deployments, the harness stops the API
server and etcd by pid and starts them again (same flags, ports and data). The operator must
reconnect its watches and finish the rollout: no crash, the plan it made before the restart
(its id on every Deployment, status.lastPlanTime) kept, one Deployment per instance, none
without its fleet as owner or with another plan; the running fleet loses nothing.

    flock /tmp/fogfleet-bed.lock pytest e2e/tests/test_faults_control_plane.py --with-e2e
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from e2e.bed import controlplane
from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    N_INSTANCES,
    Operator,
    apply_warehouse,
    assert_pods_where_planned,
    condition_is,
    fleet,
    install_crds,
    wait_ready,
)
from e2e.faults.cost import fault_result, snapshot
from e2e.tests.rosbed import EDGE, ROBOTS, split_fleet

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.bed("restarts the bed's own kube-apiserver and etcd processes by pid"),
    pytest.mark.real,
    pytest.mark.faults,
    pytest.mark.long,
    pytest.mark.timeout(420),
]

ROS_FLEET = "cpfleet"
PLAN = "fogfleet.io/plan-id"
# measured on the 2-core bed (SIGTERM: the API server drains for 10 s): see the test's output
DOWN_BOUND_S = 60
READY_BOUND_S = 120  # from the restart's start until the warehouse is Ready


def _fleet_deployments(kube: Kube, ns: str, name: str) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = kube.kubectl_json(
        "get", "deployments", "-n", ns, "-l", f"fogfleet.io/fleet={name}"
    )["items"]
    return [d for d in items if "fogfleet.io/robot" in (d["metadata"].get("annotations") or {})]


def _plan_ids(deps: list[dict[str, Any]]) -> set[str]:
    return {d["metadata"]["annotations"].get(PLAN, "") for d in deps}


def test_apiserver_and_etcd_restart_mid_rollout_keeps_the_plan_and_loses_nothing(
    kube: Kube, cluster: Cluster, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> None:
    assert set(ROBOTS) | {EDGE} <= set(cluster.real_nodes)
    ns = namespace
    install_crds(kube)
    op = Operator(kube.kubeconfig, [ns], tmp_path / "operator.log")
    diagnostics.append(lambda: ("operator log", op.logs(200)))
    op.start().wait_live()
    try:
        kube.apply(split_fleet(ns, ROS_FLEET))
        wait_ready(kube, ns, ROS_FLEET, timeout=240)
        kube.wait_for(
            "the ROS fleet's cycles counted",
            lambda: all(
                c.get("cycles", 0) > 5 for c in snapshot(kube, ns, ROS_FLEET).counters.values()
            ),
            90,
            interval=2,
        )
        before = snapshot(kube, ns, ROS_FLEET)
        assert len(before.counters) == 6, sorted(before.counters)

        apply_warehouse(kube, ns)
        kube.wait_for(
            "the warehouse planned and its rollout begun",
            lambda: bool(_fleet_deployments(kube, ns, "warehouse")),
            120,
            interval=0.2,
        )
        deps = _fleet_deployments(kube, ns, "warehouse")
        (plan_id,) = _plan_ids(deps)
        planned_at = (fleet(kube, ns).get("status") or {}).get("lastPlanTime")
        ready_at_restart = condition_is(kube, ns, "Ready", "True")
        at_restart = len(deps)
        print(f"restart at {at_restart}/{N_INSTANCES} Deployments, plan {plan_id}")

        t0 = time.monotonic()
        restart = controlplane.restart_components(cluster.ports)
        print(f"control plane: {restart}")
        assert restart.down_seconds <= DOWN_BOUND_S
        # kube-controller-manager marks the pods of nodes whose Leases went stale while the
        # API was down unready; kubelets report them ready again, kwok's fake ones need help
        re_readied: set[str] = set()

        def warehouse_ready() -> bool:
            re_readied.update(cluster.ready_fake_pods_again(ns))
            return condition_is(kube, ns, "Ready", "True")

        kube.wait_for("RobotFleet warehouse Ready", warehouse_ready, 240, interval=2)
        ready_s = time.monotonic() - t0
        wait_ready(kube, ns, ROS_FLEET, timeout=60)
        after = snapshot(kube, ns, ROS_FLEET)

        # the operator lived through it, and said nothing it should not have
        assert op.proc is not None and op.proc.poll() is None, op.logs()
        assert op.starts == 1
        log = op.log_path.read_text(errors="replace")
        assert "Traceback" not in log, op.logs(200)
        # the plan made before the restart is the one rolled out, once per instance
        deps = _fleet_deployments(kube, ns, "warehouse")
        ids = Counter(
            (d["metadata"]["annotations"]["fogfleet.io/robot"],
             d["metadata"]["annotations"]["fogfleet.io/module"]) for d in deps
        )  # fmt: skip
        assert len(ids) == N_INSTANCES and max(ids.values()) == 1, ids
        assert _plan_ids(deps) == {plan_id}, _plan_ids(deps)
        # planned once: before the restart (its status may not have been written by then)
        assert log.count(f"Planned RobotFleet {ns}/warehouse") == 1, op.logs(200)
        status = fleet(kube, ns)["status"]
        assert planned_at in (None, status.get("lastPlanTime")), (planned_at, status)
        owner = fleet(kube, ns)["metadata"]["uid"]
        assert all(d["metadata"]["ownerReferences"][0]["uid"] == owner for d in deps)
        # nothing orphaned: every Deployment in the namespace has a fleet as its owner
        everything = kube.kubectl_json("get", "deployments", "-n", ns)["items"]
        orphans = [d["metadata"]["name"] for d in everything
                   if not d["metadata"].get("ownerReferences")]  # fmt: skip
        assert not orphans, orphans
        assert_pods_where_planned(kube, ns)
        # the running fleet on the real nodes: nothing re-created, nothing lost
        lost, missed = before.messages_lost(after), before.cycles_missed(after)
        replaced = before.replaced(after)
        fault_result(
            "kube-apiserver+etcd restart mid-rollout",
            messagesLost=lost,
            cyclesMissed=missed,
            cycles=before.cycles(after),
            recoverySeconds=round(ready_s, 1),
            apiDownSeconds=round(restart.down_seconds, 1),
            deploymentsAtRestart=at_restart,
            readyAtRestart=ready_at_restart,
            fakePodsMarkedUnready=len(re_readied),
            fogfleetDid="reconnected its watches; finished the rollout with the same plan id",
            beforeFix="(no fix needed)",
        )
        assert not replaced, replaced
        assert lost <= 12, lost  # in flight at the two scrapes (2 robots x 2 flows, 10 Hz)
        assert missed <= 5, missed
        assert ready_s <= READY_BOUND_S, ready_s
    finally:
        kube.kubectl("delete", "robotfleets", "--all", "-n", ns, "--wait=true",
                     "--timeout=60s", check=False, timeout=90)  # fmt: skip
        op.stop()
