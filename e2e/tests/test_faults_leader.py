"""The in-cluster operator's leader killed during a rollout of 40 pods, then again during an
incremental re-plan (issue 37, item 4).

The chart runs two replicas on a real node; a ROS 2 fleet runs on the real nodes (its
workloads count messages and cycles) and the warehouse (40 instances) goes to kwok's nodes.
The leader pod is deleted with grace 0 right after the warehouse is applied (it has planned
and begun creating Deployments), and again right after a spec change that moves a few
instances (an edge node taken out of spec.nodes). The standby must take the Lease and finish
from what is in the cluster: one plan id on every Deployment, no instance's pod moved twice
by one plan (each pod's node is polled every 0.5 s, with its Deployment's plan id), no
Deployment or Service without its fleet as owner. After the rollout no pod moved twice at all;
after the re-plan an instance the dying leader moved may move once more (docs/survives.md).

    flock /tmp/fogfleet-bed.lock pytest e2e/tests/test_faults_leader.py --with-e2e
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import pytest

from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import (
    N_INSTANCES,
    apply_warehouse,
    assert_pods_where_planned,
    example_docs,
    fleet,
    wait_ready,
)
from e2e.faults.cost import NodeHistory, Snapshot, fault_result, snapshot
from e2e.faults.fewest import fewest_to_move
from e2e.tests.incluster import installed, kill_leader
from e2e.tests.rosbed import EDGE, ROBOTS, split_fleet

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.long,
    pytest.mark.bed("the chart on the bed's real nodes (its image imported there), kwok nodes"),
    pytest.mark.real,
    pytest.mark.incluster,
    pytest.mark.faults,
    pytest.mark.timeout(600),
]

ROS_FLEET = "leadfleet"
PLAN = "fogfleet.io/plan-id"
# the product's figure: the chart's Lease is 15 s; the standby's retry adds to it (timed from
# the delete to the new holder's acquireTime, not by the test's polling)
FAILOVER_BOUND_S = 30
# from the kill until the fleet is Ready again (2 cores, a GA run): the recovery figure the
# docs quote; its polling adds at most a second (wait_ready's interval)
READY_BOUND_S = 180


@pytest.fixture(scope="module")
def watched(kube: Kube, cluster: Cluster) -> Iterator[str]:
    """The installed operator's namespace, with the ROS fleet running on the real nodes."""
    assert set(ROBOTS) | {EDGE} <= set(cluster.real_nodes)
    with installed(kube, "e2e-faults-leader") as ns:
        kube.apply(split_fleet(ns, ROS_FLEET))
        wait_ready(kube, ns, ROS_FLEET, timeout=300)
        kube.wait_for(
            "the ROS fleet's cycles counted",
            lambda: _counting(kube, ns),
            120,
            interval=2,
        )
        yield ns
        kube.kubectl("delete", "robotfleets", "--all", "-n", ns, "--wait=true",
                     "--timeout=60s", check=False, timeout=90)  # fmt: skip


def _counting(kube: Kube, ns: str) -> bool:
    counters = snapshot(kube, ns, ROS_FLEET).counters
    return len(counters) == 6 and all(c.get("cycles", 0) > 5 for c in counters.values())


def _warehouse_deployments(kube: Kube, ns: str) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = kube.kubectl_json(
        "get", "deployments", "-n", ns, "-l", "fogfleet.io/fleet=warehouse"
    )["items"]
    return [d for d in items if "fogfleet.io/robot" in (d["metadata"].get("annotations") or {})]


def _settled(kube: Kube, ns: str) -> tuple[set[str], dict[str, Any]]:
    """Every Deployment of the warehouse: one per instance, owned by the fleet; nothing in the
    namespace without an owner. Returns the plan ids on them and the fleet's status."""
    deps = _warehouse_deployments(kube, ns)
    ids = Counter(
        (d["metadata"]["annotations"]["fogfleet.io/robot"],
         d["metadata"]["annotations"]["fogfleet.io/module"]) for d in deps
    )  # fmt: skip
    assert len(ids) == N_INSTANCES and max(ids.values()) == 1, ids
    obj = fleet(kube, ns)
    owner = obj["metadata"]["uid"]
    assert all(d["metadata"]["ownerReferences"][0]["uid"] == owner for d in deps)
    for kind in ("deployments", "services"):
        items = kube.kubectl_json("get", kind, "-n", ns)["items"]
        orphans = [i["metadata"]["name"] for i in items
                   if not i["metadata"].get("ownerReferences")]  # fmt: skip
        assert not orphans, (kind, orphans)
    assert_pods_where_planned(kube, ns)
    return {d["metadata"]["annotations"].get(PLAN, "") for d in deps}, obj["status"]


def _report(
    fault: str,
    before: Snapshot,
    after: Snapshot,
    failover: float,
    ready: float,
    moves: dict[str, int],
    did: str,
    needed: int = 0,
) -> None:
    lost, missed = before.messages_lost(after), before.cycles_missed(after)
    moved = sum(1 for n in moves.values() if n)
    fault_result(
        fault,
        messagesLost=lost,
        cyclesMissed=missed,
        missedBy=before.missed_by_module(after),
        cycles=before.cycles(after),
        recoverySeconds=round(ready, 1),
        failoverSeconds=round(failover, 1),
        instancesMoved=moved,
        movedTwice=sum(1 for n in moves.values() if n > 1),
        hadToMove=needed,
        fogfleetDid=f"{did}; {moved} instances moved, {needed} had to",
        beforeFix="(no fix yet)" if moved > needed else "(no fix needed)",
    )
    assert not before.replaced(after), before.replaced(after)
    assert lost <= 12, lost  # in flight at the two scrapes (2 robots x 2 flows, 10 Hz)
    assert missed <= 5, missed


def test_leader_killed_during_a_40_pod_rollout(kube: Kube, watched: str) -> None:
    ns = watched
    before = snapshot(kube, ns, ROS_FLEET)
    with NodeHistory(kube, ns, "fogfleet.io/fleet=warehouse") as history:
        apply_warehouse(kube, ns)
        kube.wait_for(
            "the leader planned the warehouse and began its rollout",
            lambda: bool(_warehouse_deployments(kube, ns)),
            180,
            interval=0.2,
        )
        at_kill = len(_warehouse_deployments(kube, ns))
        t0 = time.monotonic()
        new, failover = kill_leader(kube, FAILOVER_BOUND_S)
        print(f"leader killed at {at_kill}/{N_INSTANCES} Deployments; {new} leads after "
              f"{failover:.1f}s")  # fmt: skip
        wait_ready(kube, ns, timeout=READY_BOUND_S + 60)
        ready = time.monotonic() - t0
        history.caught_up()  # a last poll of where the pods are
    plans, _ = _settled(kube, ns)
    moves = history.moves()
    assert len(moves) == N_INSTANCES, sorted(moves)
    _report(
        "operator leader killed during a 40-pod rollout",
        before,
        snapshot(kube, ns, ROS_FLEET),
        failover,
        ready,
        moves,
        "the standby took the Lease and finished the rollout from the cluster's Deployments",
    )
    assert len(plans) == 1, plans
    assert max(moves.values()) <= 1, {i: history.nodes[i] for i, n in moves.items() if n > 1}
    assert failover <= FAILOVER_BOUND_S
    assert ready <= READY_BOUND_S


def test_leader_killed_during_an_incremental_replan(kube: Kube, watched: str) -> None:
    ns = watched
    wait_ready(kube, ns)
    (plan_before,), status = _settled(kube, ns)
    per_node = Counter(p["node"] for p in status["placement"])
    spec_nodes = fleet(kube, ns)["spec"]["nodes"]
    # the edge node holding the fewest instances (but some) leaves the fleet: they move
    gone = min((n for n in spec_nodes if per_node[n]), key=lambda n: per_node[n])
    moving = {f"{p['robot']}/{p['module']}" for p in status["placement"] if p["node"] == gone}
    kept_nodes = [n for n in spec_nodes if n != gone]
    # what had to move: those on the node that left and the fewest others that make room
    needed = fewest_to_move(example_docs("warehouse", ns), kept_nodes, status["placement"])
    before = snapshot(kube, ns, ROS_FLEET)
    with NodeHistory(kube, ns, "fogfleet.io/fleet=warehouse") as history:
        history.caught_up()  # where everything is now, before the patch
        patch = {"spec": {"nodes": kept_nodes}}
        kube.kubectl("patch", "robotfleet", "warehouse", "-n", ns, "--type=merge",
                     "-p", json.dumps(patch))  # fmt: skip
        generation = fleet(kube, ns)["metadata"]["generation"]
        t0 = time.monotonic()
        new, failover = kill_leader(kube, FAILOVER_BOUND_S)
        kube.wait_for(
            "the new leader's re-plan",
            lambda: (fleet(kube, ns).get("status") or {}).get("observedGeneration") == generation,
            READY_BOUND_S,
        )
        wait_ready(kube, ns, timeout=READY_BOUND_S)
        ready = time.monotonic() - t0
        history.caught_up()
    plans, status = _settled(kube, ns)
    assert gone not in {p["node"] for p in status["placement"]}
    moves = history.moves()
    moved = {i: history.nodes[i] for i, n in moves.items() if n}
    print(f"{gone} left the fleet ({len(moving)} instances on it, {needed} had to move); {new} "
          f"leads after {failover:.1f}s; moved: {moved}")  # fmt: skip
    _report(
        "operator leader killed during an incremental re-plan",
        before,
        snapshot(kube, ns, ROS_FLEET),
        failover,
        ready,
        moves,
        "the standby re-planned incrementally around the placement it found in the cluster "
        "(it has no last decision in memory: it kept what runs)",
        needed,
    )
    # The Deployments a plan moved carry its id; those it left as they were keep the id of the
    # plan that wrote them (the plan id is not a reason to rewrite a Deployment). New ids: the
    # new leader's, and the dying leader's where it had rolled out part of its re-plan.
    new_plans = plans - {plan_before}
    assert 1 <= len(new_plans) <= 2, plans
    deps = _warehouse_deployments(kube, ns)
    changed = {d["metadata"]["name"]: d["metadata"]["annotations"].get(PLAN)
               for d in deps if moves.get(d["metadata"]["name"])}  # fmt: skip
    assert changed and set(changed.values()) <= new_plans, changed
    # No plan moves an instance twice. An instance the dying leader's incremental plan had
    # already moved may be moved again by the new leader's whole-fleet plan (it has no last
    # decision in memory; docs/survives.md): one move per plan, counted in movedTwice.
    twice = history.moved_twice_by_one_plan()
    assert not twice, {i: (history.nodes[i], twice[i]) for i in twice}
    # the new leader kept what runs: at most twice what had to move (issue 46; a whole-fleet
    # plan moved 20 instances here where 6 had to)
    assert len(moved) <= 2 * needed, (moved, needed)
    assert "kept what runs" in status.get("choiceReason", ""), status.get("choiceReason")
    assert failover <= FAILOVER_BOUND_S
    assert ready <= READY_BOUND_S
