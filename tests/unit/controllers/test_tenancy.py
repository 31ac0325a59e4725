"""Fleets that share nodes: each plans into what the others left (issue 35)."""

from __future__ import annotations

import copy

import pytest

from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.errors import Infeasible
from fogfleet.render.wiring import is_ros_object
from fogfleet.snapshot.room import held_by_others

A = ("warehouse", "warehouse")
B = ("warehouse-b", "warehouse")


def copy_fleet(kube, namespace: str, robots: list[str] | None = None) -> None:
    """The warehouse fleet and its modules once more in ``namespace``: the same edge nodes,
    the same robots unless ``robots`` says which."""
    for (ns, _), module in list(kube.modules.items()):
        if ns == A[0]:
            kube.add(
                {
                    **copy.deepcopy(module),
                    "metadata": {
                        **module["metadata"],
                        "namespace": namespace,
                        "uid": f"uid-{namespace}-{module['metadata']['name']}",
                    },
                }
            )
    fleet = copy.deepcopy(kube.fleets[A])
    fleet["metadata"] = {**fleet["metadata"], "namespace": namespace, "uid": f"uid-{namespace}"}
    if robots is not None:
        fleet["spec"]["robots"] = robots
    kube.add(fleet)


def planned_cpu(kube) -> dict[str, float]:
    """Node -> the CPU every fleet's module Deployments request there."""
    out: dict[str, float] = {}
    for dep in kube.deployments.values():
        if is_ros_object(dep):
            continue  # the robots' discovery servers are not part of a plan
        spec = dep["spec"]["template"]["spec"]
        terms = spec["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"]
        nodes = terms["nodeSelectorTerms"][0]["matchExpressions"][0]["values"]
        if len(nodes) != 1:
            continue
        cpu = sum(parse_cpu(c["resources"]["requests"]["cpu"]) for c in spec["containers"])
        out[nodes[0]] = out.get(nodes[0], 0.0) + cpu * dep["spec"].get("replicas", 1)
    return out


def capacity(kube) -> dict[str, float]:
    out = {}
    for cn in kube.compute_nodes.values():
        spec = cn["spec"]
        reserved = parse_cpu((spec.get("reserved") or {}).get("cpu", 0))
        out[spec.get("nodeName") or cn["metadata"]["name"]] = (
            parse_cpu(spec["capacity"]["cpu"]) - reserved
        )
    return out


def shrink_edges(kube, cpu: str) -> None:
    for cn in kube.compute_nodes.values():
        if cn["spec"]["tier"] == "edge":
            cn["spec"]["capacity"]["cpu"] = cpu
            cn["metadata"]["generation"] += 1


def test_a_second_fleet_plans_into_what_the_first_left(kube, deps) -> None:
    kube.fleets[A]["spec"]["robots"] = ["robot-1", "robot-2"]
    copy_fleet(kube, B[0], robots=["robot-3", "robot-4"])
    shrink_edges(kube, "4")  # room for about one fleet's offloaded modules
    reconcile(kube.get_fleet(*A), deps)
    first = planned_cpu(kube)
    reconcile(kube.get_fleet(*B), deps)
    both = planned_cpu(kube)
    room = capacity(kube)
    for node, cpu in both.items():
        assert cpu <= room[node] + 1e-9, (node, cpu, room[node])
    assert both != first  # the second fleet placed something
    shared = kube.fleets[B]["status"].get("sharedNodes") or []
    assert shared and all("RobotFleet warehouse/warehouse" in s["heldBy"] for s in shared)
    assert {s["node"] for s in shared} <= {n for n, c in first.items() if c > 0}


def test_a_fleet_that_no_longer_fits_names_who_holds_the_room(kube, deps) -> None:
    copy_fleet(kube, B[0])  # the same robots: their on-board modules are A's already
    reconcile(kube.get_fleet(*A), deps)
    before = copy.deepcopy({k: d for k, d in kube.deployments.items() if k[0] == A[0]})
    with pytest.raises(Infeasible) as err:
        reconcile(kube.get_fleet(*B), deps)
    assert "(RobotFleet warehouse/warehouse " in str(err.value) and " cores" in str(err.value)
    conditions = {c["type"]: c for c in kube.fleets[B]["status"]["conditions"]}
    assert conditions["Scheduled"]["status"] == "False"
    assert {k: d for k, d in kube.deployments.items() if k[0] == A[0]} == before  # undisturbed


def test_other_fleets_hold_the_larger_of_their_plan_and_their_pods() -> None:
    def pod(ns: str, fleet: str | None, node: str, cpu: float) -> dict:
        labels = (
            {"fogfleet.io/fleet": fleet, "app.kubernetes.io/managed-by": "fogfleet"}
            if fleet
            else {}
        )
        return {
            "metadata": {"namespace": ns, "labels": labels},
            "spec": {"nodeName": node},
            "requests": {"cpu": cpu, "memory": 0.0},
        }

    loads = [
        pod("a", "f", "edge-1", 0.5),  # fleet a/f runs 0.5 where it plans 1.0
        pod("b", "g", "edge-1", 0.25),  # fleet b/g: no plan (k8s-default): its pods count
        pod("kube-system", None, "edge-1", 0.1),  # a DaemonSet's pod
        pod("me", "me", "edge-1", 3.0),  # the fleet planning: not held by others
    ]
    held = held_by_others(("me", "me"), loads, {("a", "f"): {"edge-1": (1.0, 0.0)}})
    assert held["edge-1"].cpu == pytest.approx(1.0 + 0.25 + 0.1)
    assert set(held["edge-1"].holders) == {
        "RobotFleet a/f",
        "RobotFleet b/g",
        "pods in kube-system",
    }
