"""reconcile() against an in-memory cluster: planning, idempotence, stickiness, failures."""

from __future__ import annotations

import copy

import pytest

from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.controllers.fleet.reconcile import reconcile
from fogfleet.errors import DanglingReference, Infeasible
from fogfleet.render.deployments import identity_of
from fogfleet.render.names import discovery_service_name, robot_network_policy_name
from fogfleet.render.wiring import is_ros_object

KEY = ("warehouse", "warehouse")


def run(kube, deps):
    return reconcile(kube.get_fleet(*KEY), deps)


def conditions(kube) -> dict[str, dict]:
    return {c["type"]: c for c in kube.fleets[KEY]["status"]["conditions"]}


def module_deps(kube) -> dict:
    """The modules' Deployments (not the robots' ROS discovery servers)."""
    return {k: d for k, d in kube.deployments.items() if not is_ros_object(d)}


def placement(kube) -> dict[tuple, str]:
    out = {}
    for dep in module_deps(kube).values():
        node = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"]
        out[identity_of(dep)] = node[0]
    return out


def test_first_reconcile_plans_applies_every_instance_and_waits_for_pods(kube, deps):
    out = run(kube, deps)
    assert out.planned and out.applied == 40 and not out.ready and out.requeue_after
    assert len(module_deps(kube)) == 40
    cond = conditions(kube)
    assert cond["Ready"]["status"] == "False" and cond["Ready"]["reason"] == "RollingOut"
    assert cond["Scheduled"]["status"] == "True"
    status = kube.fleets[KEY]["status"]
    assert status["modulesPlaced"] == status["modulesTotal"] == 40
    assert len(status["placement"]) == 40 and status["observedGeneration"] == 1
    assert [e[1] for e in kube.events] == ["Planned"]


def test_the_miss_column_shows_the_prediction_as_the_cli_does(kube, deps):
    """kubectl's MISS column reads status.predictedMiss: the fraction as a percentage in the
    CLI's format (issue 36), and the Planned Event says the same."""
    from fogfleet.domain.miss_rates import format_miss_rate

    run(kube, deps)
    status = kube.fleets[KEY]["status"]
    shown = status["predictedMiss"]
    assert shown.endswith("%") and shown != "0.00%"
    objective = next(o["value"] for o in status["objectives"] if o["name"] == "missRate")
    assert shown == format_miss_rate(objective) or shown == "<0.0001%"
    assert f"predicted miss rate {shown}" in kube.events[0][2]


def test_the_plan_says_how_far_its_s_is_above_a_lower_bound(kube, deps):
    """status.planGap and the Planned Event (issue 46): the best scalarised S the search found
    and the deployed plan's, against the tighter of the robot and LP bounds."""
    run(kube, deps)
    gap = kube.fleets[KEY]["status"]["planGap"]
    assert gap["boundKind"] in ("robot", "lp") and not gap["timeBudgetReached"]
    assert 0 < gap["bound"] <= gap["value"] <= gap["deployedValue"]
    assert gap["percent"] == pytest.approx(100 * (gap["value"] / gap["bound"] - 1), abs=0.01)
    assert gap["deployedPercent"] >= gap["percent"]
    # the warehouse's front holds the MILP optimum of S (2 % above the robot bound, all of it
    # the bound's); its lexicographic choice, misses first, is far from it in S
    assert gap["percent"] < 5
    assert f"{gap['percent']:.1f} % above the {gap['boundKind']} bound" in kube.events[0][2]


def test_ready_once_pods_run_where_planned(kube, deps):
    run(kube, deps)
    kube.run_pods()
    out = run(kube, deps)
    assert out.ready and not out.planned and out.applied == 0
    assert conditions(kube)["Ready"]["status"] == "True"
    assert conditions(kube)["Degraded"]["status"] == "False"


def test_a_second_reconcile_with_nothing_changed_plans_and_applies_nothing(kube, deps):
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    patches, applied, calls = len(kube.status_patches), len(kube.applied), deps.planner.calls
    out = run(kube, deps)
    assert (out.planned, out.applied, out.pruned) == (False, 0, 0)
    assert (len(kube.status_patches), len(kube.applied), deps.planner.calls) == (
        patches,
        applied,
        calls,
    )


def test_a_restarted_operator_keeps_running_modules_where_they_are(kube, deps, make_deps):
    run(kube, deps)
    kube.run_pods()
    before = placement(kube)
    fresh = make_deps()  # empty cache: it plans again
    out = reconcile(kube.get_fleet(*KEY), fresh)
    assert out.planned and out.applied == 0 and out.migrations == 0
    assert placement(kube) == before


def test_a_not_ready_edge_node_moves_only_its_modules(kube, deps):
    # no move for a better plan alone (the small test budget leaves room to improve on every
    # re-plan), and a spare edge node so the lost node's modules fit without moving others
    scheduler = kube.fleets[KEY]["spec"].setdefault("scheduler", {})
    scheduler["migrationMarginPercent"] = 100
    # the whole-fleet plan after the restart (an incremental one would keep what runs itself)
    scheduler["incremental"] = False
    run(kube, deps)
    kube.run_pods()
    before = placement(kube)
    used = sorted({n for n in before.values() if n.startswith("edge")})
    assert used, "the plan should use an edge node"
    spare = copy.deepcopy(kube.compute_nodes[used[0]])
    spare["metadata"] = {"name": "edge-spare", "generation": 1, "uid": "uid-edge-spare"}
    kube.compute_nodes["edge-spare"] = spare
    node = copy.deepcopy(kube.nodes[used[0]])
    node["metadata"]["name"] = "edge-spare"
    kube.nodes["edge-spare"] = node
    kube.fleets[KEY]["spec"]["nodes"].append("edge-spare")
    kube.fleets[KEY]["metadata"]["generation"] += 1
    kube.set_ready(used[0], False)
    out = run(kube, deps)
    after = placement(kube)
    moved = {k for k in before if before[k] != after[k]}
    assert moved == {k for k, n in before.items() if n == used[0]}
    assert used[0] not in after.values()
    assert out.planned and out.migrations == len(moved)
    cond = conditions(kube)
    assert cond["Degraded"]["status"] == "True" and cond["Degraded"]["reason"] == "Migrating"
    assert "Migrated" in [e[1] for e in kube.events]
    kube.run_pods()
    assert run(kube, deps).ready


def test_a_changed_cycle_time_replans_once_and_leaves_the_others_alone(kube, deps):
    run(kube, deps)
    kube.run_pods()
    before = {
        k: d["metadata"]["annotations"]["fogfleet.io/spec-hash"]
        for k, d in module_deps(kube).items()
    }
    mod = kube.modules[("warehouse", "arm-motion-generation")]
    mod["spec"]["cycleTimeMillis"] = 400
    mod["metadata"]["generation"] += 1
    calls = deps.planner.calls
    kube.applied.clear()
    before_nodes = placement(kube)
    out = run(kube, deps)
    assert deps.planner.calls == calls + 1
    changed = {
        k[1]
        for k, d in module_deps(kube).items()
        if d["metadata"]["annotations"]["fogfleet.io/spec-hash"] != before[k]
    }
    assert set(kube.applied) == changed
    after_nodes = placement(kube)
    others = {
        k
        for k in before_nodes
        if k[1] != "arm-motion-generation" and before_nodes[k] != after_nodes[k]
    }
    assert len(others) <= out.migrations, "every other module that changed was moved and counted"
    assert len(changed) <= 5 + out.migrations


def _planned_then_dangling(kube, deps) -> dict:
    """Plan the fleet, then reconcile it with a module reference to nothing (generation 2);
    the Deployments as planned."""
    run(kube, deps)
    snapshot = {k: dict(v) for k, v in kube.deployments.items()}
    kube.fleets[KEY]["spec"]["modules"].append({"name": "no-such-module"})
    kube.fleets[KEY]["metadata"]["generation"] = 2
    with pytest.raises(DanglingReference):
        run(kube, deps)
    return snapshot


def test_a_dangling_module_reference_fails_without_touching_what_runs(kube, deps):
    snapshot = _planned_then_dangling(kube, deps)
    cond = conditions(kube)
    assert cond["Ready"]["status"] == "False" and cond["Ready"]["reason"] == "DanglingReference"
    assert "spec.modules[8].name" in cond["Ready"]["message"]
    assert ("Warning", "DanglingReference") in [e[:2] for e in kube.events]
    assert kube.deployments.keys() == snapshot.keys()


def test_a_bug_says_so_in_the_status_instead_of_the_last_reason(kube, deps, monkeypatch):
    """An unexpected error replaces a stale reason (a dangling reference since created) with
    ReconcileError and the error, and goes on to the queue's retry; nothing runs changes."""
    snapshot = _planned_then_dangling(kube, deps)
    kube.fleets[KEY]["spec"]["modules"].pop()
    kube.fleets[KEY]["metadata"]["generation"] = 3

    def broken(*_, **__):
        raise ValueError("cannot reshape array of size 0")

    monkeypatch.setattr("fogfleet.controllers.fleet.reconcile.plan_step", broken)
    with pytest.raises(ValueError, match="reshape"):
        run(kube, deps)
    cond = conditions(kube)
    assert cond["Ready"]["status"] == "False" and cond["Ready"]["reason"] == "ReconcileError"
    assert "ValueError: cannot reshape array of size 0" in cond["Ready"]["message"]
    assert cond["Scheduled"]["reason"] == "ReconcileError"
    assert ("Warning", "ReconcileError") in [e[:2] for e in kube.events]
    assert kube.deployments.keys() == snapshot.keys()


def test_a_fleet_that_cannot_fit_is_reported_and_nothing_is_applied(kube, deps):
    for cn in kube.compute_nodes.values():
        cn["spec"]["capacity"] = {"cpu": 3, "memory": "16Gi"}
        cn["spec"]["reserved"] = {"cpu": "0", "memory": "0"}
    with pytest.raises(Infeasible):
        run(kube, deps)
    assert not kube.deployments
    cond = conditions(kube)
    assert cond["Ready"]["reason"] == "Infeasible"
    assert ("Warning", "PlanFailed") in [e[:2] for e in kube.events]
    calls = deps.planner.calls
    with pytest.raises(Infeasible):
        run(kube, deps)
    assert deps.planner.calls == calls, "same inputs, same failure: no second GA run"


@pytest.mark.integration
def test_a_fleet_short_of_cpu_runs_degraded_and_says_so(kube, deps):
    from fogfleet.adapters.metrics import PrometheusMetrics

    deps.metrics = PrometheusMetrics()
    for cn in kube.compute_nodes.values():
        if cn["spec"]["tier"] == "edge":
            cn["spec"]["capacity"] = {"cpu": 4, "memory": "64Gi"}
    out = run(kube, deps)
    assert out.applied == 40, "a degraded plan runs every module"
    cond = conditions(kube)
    assert cond["Degraded"]["status"] == "True" and cond["Degraded"]["reason"] == "ShortOfCapacity"
    assert "predicted miss" in cond["Degraded"]["message"]
    assert ("Warning", "ShortOfCapacity") in [e[:2] for e in kube.events]
    gauge = deps.metrics.registry.get_sample_value(
        "fogfleet_degraded_instances", {"fleet": "warehouse"}
    )
    assert gauge is not None and gauge >= 1
    # the Deployments request the smaller CPU the plan guarantees them (status.placement)
    # and degraded ones may burst to what their deadline needs (a higher limit)
    status = {(p["robot"], p["module"]): p["cpu"] for p in kube.fleets[KEY]["status"]["placement"]}
    burst = 0
    for dep in module_deps(kube).values():
        robot, module, _ = identity_of(dep)
        res = dep["spec"]["template"]["spec"]["containers"][0]["resources"]
        assert res["requests"]["cpu"] == status[(robot, module)]
        # beyond the default headroom (twice the request): what the deadline needs, doubled
        burst += parse_cpu(res["limits"]["cpu"]) > 2 * parse_cpu(res["requests"]["cpu"])
    assert burst > 0


def test_stale_deployments_are_pruned(kube, deps):
    run(kube, deps)
    kube.fleets[KEY]["spec"]["modules"] = kube.fleets[KEY]["spec"]["modules"][:7]
    kube.fleets[KEY]["metadata"]["generation"] = 2
    out = run(kube, deps)
    assert out.pruned == 5 and len(module_deps(kube)) == 35


def test_the_k8s_default_fleet_records_kube_schedulers_placement(kube, deps):
    kube.fleets[KEY]["spec"]["scheduler"] = {"algorithm": "k8s-default"}
    out = run(kube, deps)
    assert not out.planned and deps.planner.calls == 0 and out.applied == 40
    dep = next(iter(module_deps(kube).values()))
    assert "limits" not in dep["spec"]["template"]["spec"]["containers"][0]["resources"]
    assert kube.fleets[KEY]["status"]["placement"] == []
    kube.run_pods()
    out = run(kube, deps)
    status = kube.fleets[KEY]["status"]
    assert out.ready and len(status["placement"]) == 40
    assert status["predictedMissRate"] is not None
    assert conditions(kube)["Scheduled"]["reason"] == "KubeScheduler"


def test_an_onboard_fleet_runs_its_nominal_requests_even_where_its_limits_would_not_fit(kube, deps):
    """onboard is the paper's baseline of plain Deployments on the robot (nominal requests, no
    limits): the robots cannot hold every module's deadline CPU, and they need not."""
    kube.fleets[KEY]["spec"]["scheduler"] = {"algorithm": "onboard"}
    out = run(kube, deps)
    assert out.applied == 40
    for dep in module_deps(kube).values():
        robot, _, _ = identity_of(dep)
        assert placement(kube)[identity_of(dep)] == robot
        assert "limits" not in dep["spec"]["template"]["spec"]["containers"][0]["resources"]
    assert conditions(kube)["Scheduled"]["status"] == "True"


def test_a_paused_fleet_is_left_alone(kube, deps):
    kube.fleets[KEY]["spec"]["paused"] = True
    run(kube, deps)
    assert not kube.deployments
    assert conditions(kube)["Scheduled"]["reason"] == "Paused"


def _env(dep: dict) -> dict[str, str]:
    container = dep["spec"]["template"]["spec"]["containers"][0]
    return {e["name"]: e.get("value", "") for e in container.get("env", [])}


def test_every_robot_gets_a_discovery_server_on_its_own_node_and_its_modules_use_it(kube, deps):
    run(kube, deps)
    servers = {k[1]: d for k, d in kube.deployments.items() if is_ros_object(d)}
    assert len(servers) == 5 and len(kube.services) == 5
    for dep in servers.values():
        robot = dep["metadata"]["labels"]["fogfleet.io/robot"]
        assert dep["metadata"]["name"] == discovery_service_name("warehouse", robot)
        assert dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"][0]["matchExpressions"][0]["values"] == [robot]
        # it stays on its robot while the robot is cut off (no eviction)
        tolerated = {t["key"] for t in dep["spec"]["template"]["spec"]["tolerations"]}
        assert {"node.kubernetes.io/unreachable", "node.kubernetes.io/not-ready"} <= tolerated
        assert "fogfleet.io/dedicated" in tolerated  # the bed taints the nodes it simulates
    ips = {k[1]: s["spec"]["clusterIP"] for k, s in kube.services.items()}
    # each Service selects its own robot's server pod, never another robot's
    for (_, name), svc in kube.services.items():
        robot = svc["spec"]["selector"]["fogfleet.io/robot"]
        assert name == discovery_service_name("warehouse", robot)
        (server,) = [d for d in servers.values() if d["metadata"]["name"] == name]
        labels = server["spec"]["template"]["metadata"]["labels"]
        assert svc["spec"]["selector"].items() <= labels.items()
        others = [d for d in servers.values() if d["metadata"]["name"] != name]
        assert not any(
            svc["spec"]["selector"].items() <= d["spec"]["template"]["metadata"]["labels"].items()
            for d in others
        )
    offloaded = 0
    for dep in module_deps(kube).values():
        robot = dep["metadata"]["annotations"]["fogfleet.io/robot"]
        env = _env(dep)
        # wherever the module runs, it discovers through its own robot's server
        assert (
            env["ROS_DISCOVERY_SERVER"]
            == f"{ips[discovery_service_name('warehouse', robot)]}:11811"
        )
        assert env["FOGFLEET_ROBOT"] == robot and env["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
        offloaded += env["FOGFLEET_TIER"] != "robot"
    assert offloaded > 0, "the plan offloads something, so discovery must cross nodes"
    # a second reconcile keeps the servers and their addresses
    run(kube, deps)
    assert {k[1]: s["spec"]["clusterIP"] for k, s in kube.services.items()} == ips


def test_an_unchanged_fleet_writes_nothing_again_and_a_changed_server_is_reapplied(kube, deps):
    deps.full_reconcile_seconds = 0.0  # the full pass every time, not a status refresh
    run(kube, deps)
    assert len(kube.applied_services) == 5 and len(kube.applied) == 45  # 40 modules + 5 servers
    policies = len(kube.applied_policies)
    assert policies == len(kube.network_policies) > 0
    ips = {k[1]: s["spec"]["clusterIP"] for k, s in kube.services.items()}
    kube.run_pods()
    run(kube, deps)
    assert len(kube.applied_services) == 5 and len(kube.applied) == 45
    assert len(kube.applied_policies) == policies  # one apply engine: NetworkPolicies too
    kube.fleets[KEY]["spec"]["ros"] = {"discoveryServerPort": 11911}
    kube.fleets[KEY]["metadata"]["generation"] = 2
    run(kube, deps)
    assert len(kube.applied_services) == 10  # every Service again, with the new port
    assert {k[1]: s["spec"]["clusterIP"] for k, s in kube.services.items()} == ips
    env = _env(next(iter(module_deps(kube).values())))
    assert env["ROS_DISCOVERY_SERVER"].endswith(":11911")


def test_a_robot_leaving_the_fleet_takes_its_discovery_server_along(kube, deps):
    run(kube, deps)
    kube.fleets[KEY]["spec"]["robots"] = kube.fleets[KEY]["spec"]["robots"][:4]
    kube.fleets[KEY]["metadata"]["generation"] = 2
    run(kube, deps)
    assert len([d for d in kube.deployments.values() if is_ros_object(d)]) == 4
    assert len(kube.services) == 4


def test_a_robot_leaving_the_fleet_takes_its_network_policy_along(kube, deps):
    run(kube, deps)
    robots = list(kube.fleets[KEY]["spec"]["robots"])
    names = {name for _, name in kube.network_policies}
    fleet_wide = {"warehouse-pods", "warehouse-shared", "warehouse-metrics"}
    assert names == fleet_wide | {robot_network_policy_name("warehouse", r) for r in robots}
    for policy in kube.network_policies.values():
        refs = policy["metadata"]["ownerReferences"]
        assert [r["kind"] for r in refs] == ["RobotFleet"]  # they go with the fleet
    gone = _drop_a_robot(kube)
    run(kube, deps)
    assert ("warehouse", robot_network_policy_name("warehouse", gone)) not in kube.network_policies
    assert len(kube.network_policies) == len(robots) + 2


def _drop_a_robot(kube) -> str:
    robots = kube.fleets[KEY]["spec"]["robots"]
    kube.fleets[KEY]["spec"]["robots"] = robots[:-1]
    kube.fleets[KEY]["metadata"]["generation"] += 1
    return robots[-1]


def test_a_robot_leaving_is_replanned_incrementally_and_nothing_else_moves(kube, deps):
    run(kube, deps)
    kube.run_pods()
    before = placement(kube)
    calls = deps.planner.calls
    gone = _drop_a_robot(kube)
    out = run(kube, deps)
    assert out.planned and out.migrations == 0
    assert deps.planner.calls == calls, "no whole-fleet plan"
    assert deps.planner.replans == 1
    after = placement(kube)
    assert after == {k: n for k, n in before.items() if k[0] != gone}
    assert "incremental re-plan" in kube.fleets[KEY]["status"]["choiceReason"]


def test_incremental_false_plans_the_whole_fleet_on_every_change(kube, deps):
    kube.fleets[KEY]["spec"].setdefault("scheduler", {})["incremental"] = False
    run(kube, deps)
    kube.run_pods()
    calls = deps.planner.calls
    _drop_a_robot(kube)
    assert run(kube, deps).planned
    assert (deps.planner.calls, deps.planner.replans) == (calls + 1, 0)


def test_without_ros_wiring_modules_get_only_the_fogfleet_variables(kube, deps):
    kube.fleets[KEY]["spec"]["ros"] = {"enabled": False}
    run(kube, deps)
    assert not kube.services and all(not is_ros_object(d) for d in kube.deployments.values())
    env = _env(next(iter(module_deps(kube).values())))
    assert "ROS_DISCOVERY_SERVER" not in env and env["FOGFLEET_MODULE_SPEC"].startswith("{")


# --- regressions (issue: one source of truth) ---------------------------------------------------


class ShiftingPlanner:
    """Plans with ``inner``, then moves one running instance to another allowed node: a "new" plan
    that is never better by a 100% margin, so the running placement must be kept."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.calls = 0
        self.shift = False

    def plan(self, problem, settings):
        import dataclasses

        import numpy as np

        from fogfleet.scheduling.stickiness import objective_values

        self.calls += 1
        schedule = self.inner.plan(problem, settings)
        if not self.shift:
            return schedule
        x = np.array(schedule.placement)
        for i in range(problem.n_instances):
            others = [j for j in np.flatnonzero(problem.allowed[i]) if j != x[i]]
            if others:
                x[i] = others[-1]
                break
        values = objective_values(problem, x, True, list(schedule.objectives))
        values["missRate"] = 0.5  # a value the kept plan cannot have
        return dataclasses.replace(schedule, placement=x, objectives=values)

    def replan(self, problem, settings, changed, reference):
        return self.inner.replan(problem, settings, changed, reference)


@pytest.mark.integration
def test_status_reports_the_objectives_of_the_placement_actually_deployed(kube, make_deps):
    from fogfleet.controllers.deps import Deps

    planner = ShiftingPlanner(make_deps().planner)
    deps = Deps(kube=kube, planner=planner)
    scheduler = kube.fleets[KEY]["spec"].setdefault("scheduler", {})
    scheduler["migrationMarginPercent"] = 100
    # the whole-fleet plan after the restart (an incremental one would keep what runs itself)
    scheduler["incremental"] = False
    run(kube, deps)
    kube.run_pods()
    deployed = placement(kube)
    first = dict(kube.fleets[KEY]["status"])
    planner.shift = True
    fresh = Deps(kube=kube, planner=planner)  # a restart: plans again, keeps what runs
    out = reconcile(kube.get_fleet(*KEY), fresh)
    assert out.planned and out.migrations == 0 and placement(kube) == deployed
    status = kube.fleets[KEY]["status"]
    assert "kept running modules in place" in status["choiceReason"]
    # the same placement runs, so the same predictions: not the discarded plan's 0.5
    assert status["predictedMissRate"] == pytest.approx(first["predictedMissRate"])
    assert {o["name"]: o["value"] for o in status["objectives"]} == pytest.approx(
        {o["name"]: o["value"] for o in first["objectives"]}
    )
    assert "missRate 50.00%" not in " ".join(e[2] for e in kube.events)


def test_a_quantity_weight_is_accepted_by_the_solver(kube, deps):
    from fogfleet.api.v1alpha1.robotfleet import RobotFleet
    from fogfleet.scheduling.solver import weights_of

    body = kube.get_fleet(*KEY)
    body["spec"]["scheduler"] = {
        "choice": "weighted",
        "weights": [
            {"objective": "missRate", "weight": 0.5},
            {"objective": "cost", "weight": 2},
        ],
    }
    settings = RobotFleet.model_validate(body).spec.scheduler
    assert weights_of(settings) == {"missRate": 0.5, "cost": 2.0}


def test_fields_a_reconcile_stops_writing_are_removed_from_status(kube, deps):
    run(kube, deps)
    assert kube.fleets[KEY]["status"].get("choiceReason") is not None
    kube.fleets[KEY]["spec"].setdefault("scheduler", {})["algorithm"] = "k8s-default"
    kube.fleets[KEY]["metadata"]["generation"] += 1
    run(kube, deps)
    status = kube.fleets[KEY]["status"]
    for stale in ("choiceReason", "planningMillis", "lastPlanTime", "migrations"):
        assert stale not in status, stale
    patches = len(kube.status_patches)
    run(kube, deps)
    assert len(kube.status_patches) == patches  # converged: no patch on every reconcile


def test_a_robot_listed_twice_is_refused_naming_it():
    from pydantic import ValidationError

    from fogfleet.api.v1alpha1.robotfleet import RobotFleetSpec

    with pytest.raises(ValidationError, match=r"robots: robot-1 listed more than once"):
        RobotFleetSpec.model_validate(
            {"robots": ["robot-1", "robot-1"], "modules": [{"name": "m"}]}
        )
    with pytest.raises(ValidationError, match=r"nodes: edge-1 listed more than once"):
        RobotFleetSpec.model_validate(
            {"robots": ["r"], "nodes": ["edge-1", "edge-1"], "modules": [{"name": "m"}]}
        )


def _standbys(kube) -> dict[str, dict]:
    """robot -> its standby Deployment (an on-board fallback)."""
    return {
        d["metadata"]["annotations"]["fogfleet.io/robot"]: d
        for d in module_deps(kube).values()
        if d["metadata"]["annotations"].get("fogfleet.io/role") == "standby"
    }


def test_a_fleet_whose_robots_cannot_hold_every_fallback_is_refused_saying_why(kube, deps):
    """The warehouse's robots are saturated by their own eight modules: holding a share for
    every offloadable one does not fit, and the fleet is refused, not silently overcommitted."""
    kube.fleets[KEY]["spec"]["fallback"] = {"mode": "onboard"}
    with pytest.raises(Infeasible) as info:
        run(kube, deps)
    assert "held for on-board fallbacks" in str(info.value)
    assert not module_deps(kube)


def test_offloaded_fallbacks_get_standbys_their_robots_keep_while_down(kube, deps):
    hpe = kube.modules[("warehouse", "human-pose-estimation")]["spec"]
    # with a fallback, offloading frees nothing on the robot: only the preference sends it out
    hpe["fallback"], hpe["preferredTiers"] = {"mode": "onboard", "cpu": 1}, ["edge"]
    scheduler = kube.fleets[KEY]["spec"].setdefault("scheduler", {})
    scheduler["migrationMarginPercent"] = 100
    # the whole-fleet plan after the restart (an incremental one would keep what runs itself)
    scheduler["incremental"] = False
    run(kube, deps)
    kube.run_pods()
    assert run(kube, deps).ready  # the standbys' pods count: they must run too
    status = kube.fleets[KEY]["status"]
    cuts = {c["robot"]: c for c in status["fallbacks"]}
    standbys = _standbys(kube)
    assert standbys, "the plan offloads modules that keep a fallback"
    for robot, dep in standbys.items():
        module = dep["metadata"]["annotations"]["fogfleet.io/module"]
        assert module in cuts[robot]["standbys"] and parse_cpu(cuts[robot]["reservedCpu"]) > 0
        assert 0 <= cuts[robot]["predictedMissRate"] <= 1
    # the placement in status is the instances', not the standbys'
    assert len(status["placement"]) == status["modulesTotal"]
    # a robot that is down (its link cut) keeps its standby and its remote instances untouched
    robot = sorted(standbys)[0]
    versions = {
        n: d["metadata"]["annotations"]["fogfleet.io/spec-hash"]
        for n, d in module_deps(kube).items()
    }
    kube.set_ready(robot, False)
    run(kube, deps)
    assert robot in _standbys(kube)
    after = {
        n: d["metadata"]["annotations"]["fogfleet.io/spec-hash"]
        for n, d in module_deps(kube).items()
    }
    assert after == versions
    # without fallbacks the standbys go and the status says nothing of them
    kube.set_ready(robot, True)
    module = kube.modules[("warehouse", "human-pose-estimation")]
    del module["spec"]["fallback"]
    module["metadata"]["generation"] += 1
    run(kube, deps)
    assert not _standbys(kube) and not kube.fleets[KEY]["status"].get("fallbacks")


def test_a_robot_that_is_down_leaves_everything_where_it_runs(kube, deps):
    """Its on-board modules are stranded (kept, reported), its offloaded ones stay on their
    nodes: nothing is re-planned around a robot whose data went with it."""
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    before = placement(kube)
    versions = {
        n: d["metadata"]["annotations"]["fogfleet.io/spec-hash"]
        for n, d in module_deps(kube).items()
    }
    kube.set_ready("robot-1", False)
    out = run(kube, deps)
    assert out.migrations == 0 and placement(kube) == before
    assert {
        n: d["metadata"]["annotations"]["fogfleet.io/spec-hash"]
        for n, d in module_deps(kube).items()
    } == versions
    cond = conditions(kube)["Ready"]
    assert (cond["status"], cond["reason"]) == ("False", "NodeUnavailable")
    assert "robot-1 is NotReady" in cond["message"]
    kube.set_ready("robot-1", True)
    assert run(kube, deps).ready and placement(kube) == before


def test_a_running_fleet_that_no_longer_fits_keeps_its_plan_and_its_status_follows_it(kube, deps):
    """A re-plan that finds no placement (here every node shrinks) touches nothing that runs;
    Ready and Scheduled say why (one PlanFailed Event per reason), and Degraded goes on saying
    where the fleet stands on its last plan (a pod elsewhere shows as moving)."""
    run(kube, deps)
    kube.run_pods()
    run(kube, deps)
    before, deployments = placement(kube), copy.deepcopy(kube.deployments)
    specs = {name: copy.deepcopy(cn["spec"]) for name, cn in kube.compute_nodes.items()}
    for cn in kube.compute_nodes.values():
        cn["spec"]["capacity"] = {"cpu": 3, "memory": "16Gi"}
        cn["spec"]["reserved"] = {"cpu": "0", "memory": "0"}
        cn["metadata"]["generation"] += 1
    out = run(kube, deps)
    assert not out.ready and not out.planned and placement(kube) == before
    assert out.requeue_after is None, "planned again when its inputs change, not on a timer"
    assert kube.deployments == deployments
    cond = conditions(kube)
    for type_ in ("Ready", "Scheduled"):
        assert (cond[type_]["status"], cond[type_]["reason"]) == ("False", "Infeasible")
        assert "the fleet runs its last plan" in cond[type_]["message"]
    assert cond["Degraded"]["reason"] == "AsPlanned"
    failed = [e for e in kube.events if e[1] == "PlanFailed"]
    assert len(failed) == 1 and failed[0][0] == "Warning"

    calls = deps.planner.calls
    moved = next(p for k, p in kube.pods.items() if "nav-controller" in k[1])
    moved["spec"]["nodeName"] = "edge-1"  # not where the last plan put it
    out = run(kube, deps)
    assert out.waiting == 1
    assert deps.planner.calls == calls, "same inputs, same failure: no second GA run"
    cond = conditions(kube)
    assert cond["Degraded"]["reason"] == "Migrating", cond["Degraded"]
    assert cond["Scheduled"]["status"] == "False"
    assert len([e for e in kube.events if e[1] == "PlanFailed"]) == 1, "one Event per reason"

    for name, cn in kube.compute_nodes.items():  # room again: planned as before
        cn["spec"] = specs[name]
        cn["metadata"]["generation"] += 1
    kube.run_pods()
    out = run(kube, deps)
    assert out.ready and placement(kube) == before
    assert conditions(kube)["Scheduled"]["status"] == "True"
