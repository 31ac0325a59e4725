"""Rendering plans into Deployments: names, affinity, resources, labels, owner, idempotence."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import Catalog, load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Instance, Problem
from fogfleet.render.deployments import (
    ANNOTATION_NODE,
    ANNOTATION_PLAN,
    ANNOTATION_SPEC_HASH,
    Owner,
    format_cpu,
    identity_of,
    label_value,
    render_fleet,
    spec_hash,
)
from fogfleet.render.names import deployment_name
from fogfleet.snapshot.objects import bound_nodes
from fogfleet.workload.spec import WorkloadSpec

EXAMPLES = Path(__file__).resolve().parents[3] / "manifests" / "examples"
DNS_LABEL = re.compile(r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")


@pytest.fixture(scope="module")
def catalog() -> Catalog:
    return load_paths([EXAMPLES / "warehouse"])


@pytest.fixture(scope="module")
def problem(catalog: Catalog) -> Problem:
    return build_problem(catalog.fleets[0], catalog)


def modules(catalog: Catalog) -> dict[str, object]:
    return {name: m for (_, name), m in catalog.modules.items()}


def first_allowed(problem: Problem) -> np.ndarray:
    return np.array([int(np.flatnonzero(row)[0]) for row in problem.allowed])


def test_every_placed_instance_gets_one_deployment_bound_to_its_node(catalog, problem):
    placement = first_allowed(problem)
    deps = render_fleet(problem, modules(catalog), placement, owner=Owner("warehouse", "u-1"))
    assert len(deps) == problem.n_instances
    for i, dep in enumerate(deps):
        terms = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        expr = terms[0]["matchExpressions"][0]
        assert expr == {
            "key": "kubernetes.io/hostname",
            "operator": "In",
            "values": [problem.nodes[placement[i]].node_name],
        }


def test_requests_are_the_planned_cpu_and_limits_leave_the_fleets_headroom(catalog, problem):
    placement = first_allowed(problem)
    planned = float(problem.limits.cpu_request[0, placement[0]])
    dep = render_fleet(problem, modules(catalog), placement)[0]
    res = dep["spec"]["template"]["spec"]["containers"][0]["resources"]
    assert res["requests"]["cpu"] == format_cpu(planned)
    assert res["limits"] == res["requests"] | {"cpu": format_cpu(2 * planned)}  # default 200 %
    exact = render_fleet(problem, modules(catalog), placement, cpu_limit_percent=100)[0]
    res = exact["spec"]["template"]["spec"]["containers"][0]["resources"]
    assert res["requests"] == res["limits"]  # Guaranteed, as in the paper


def test_a_limit_never_exceeds_what_its_node_has_for_pods():
    """The paper bed's 300m edge: segmentation planned at 267m would get a 534m limit, which a
    node whose CPU is a cgroup quota refuses (runc: cpu.cfs_quota_us invalid argument)."""
    catalog = load_paths([Path(__file__).resolve().parents[3] / "e2e" / "bench" / "real" / "paper"])
    problem = build_problem(catalog.fleets[0], catalog)
    small = next(j for j, n in enumerate(problem.nodes) if n.name == "paper-edge-2")
    seg = next(i for i, inst in enumerate(problem.instances) if inst.module == "scene-segmentation")
    placement = np.full(problem.n_instances, -1)
    placement[seg] = small
    dep = render_fleet(problem, modules(catalog), placement)[0]
    res = dep["spec"]["template"]["spec"]["containers"][0]["resources"]
    assert res["requests"]["cpu"] == "267m"
    assert res["limits"]["cpu"] == format_cpu(problem.capacity[small, 0]) == "270m"


def test_a_degraded_instance_plays_the_row_it_was_planned_to_burst_to():
    """Degraded one rung, segmentation is guaranteed 133m and may burst to the 267m its
    deadline needs; planner and simulator run it at the 267m row (85 ms), so must the pod
    (it played the 133m row, 145 ms of a 150 ms cycle, and missed 38 % on the paper bed)."""
    catalog = load_paths([Path(__file__).resolve().parents[3] / "e2e" / "bench" / "real" / "paper"])
    problem = build_problem(catalog.fleets[0], catalog)
    big = next(j for j, n in enumerate(problem.nodes) if n.name == "paper-edge-1")
    seg = next(i for i, inst in enumerate(problem.instances) if inst.module == "scene-segmentation")
    levels = np.zeros(problem.n_instances, dtype=np.int64)
    levels[seg] = 1
    degraded = problem.with_levels(levels)
    placement = np.full(problem.n_instances, -1)
    placement[seg] = big
    dep = render_fleet(degraded, modules(catalog), placement)[0]
    container = dep["spec"]["template"]["spec"]["containers"][0]
    assert container["resources"]["requests"]["cpu"] == "133m"
    assert container["resources"]["limits"]["cpu"] == "534m"
    spec = WorkloadSpec.from_env({e["name"]: e.get("value", "") for e in container["env"]})
    assert spec.row.cpu == pytest.approx(0.267)
    assert spec.row.mean_s == pytest.approx(degraded.limits.exe_mean[seg, big]) == 0.085


def test_unplaced_instances_get_no_deployment(catalog, problem):
    placement = first_allowed(problem)
    placement[3] = -1
    deps = render_fleet(problem, modules(catalog), placement)
    assert len(deps) == problem.n_instances - 1


def test_baseline_allows_the_whole_gene_space_with_nominal_requests_and_no_limits(catalog, problem):
    deps = render_fleet(problem, modules(catalog), None, baseline=True)
    for i, dep in enumerate(deps):
        pod = dep["spec"]["template"]["spec"]
        values = pod["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"][
            "nodeSelectorTerms"
        ][0]["matchExpressions"][0]["values"]
        assert values == [problem.nodes[j].node_name for j in np.flatnonzero(problem.allowed[i])]
        res = pod["containers"][0]["resources"]
        assert "limits" not in res
        j = int(np.flatnonzero(problem.allowed[i])[0])
        assert res["requests"]["cpu"] == format_cpu(problem.nominal.cpu_request[i, j])


def test_a_baseline_pod_learns_its_node_when_it_runs_and_plays_that_nodes_rows(catalog, problem):
    """kube-scheduler picks the node, so the pod reads it from the downward API and its spec
    carries the rows of every allowed node; without a limit it runs the largest parallelism."""
    deps = render_fleet(problem, modules(catalog), None, baseline=True)
    for i, dep in enumerate(deps):
        env = dep["spec"]["template"]["spec"]["containers"][0]["env"]
        by_name = {e["name"]: e for e in env}
        assert by_name["FOGFLEET_NODE"]["valueFrom"]["fieldRef"]["fieldPath"] == "spec.nodeName"
        assert "FOGFLEET_CPU" not in by_name
        allowed = np.flatnonzero(problem.allowed[i])
        for j in allowed:  # wherever it lands, it plays what the simulator's nominal assumes
            pairs = {e["name"]: e.get("value", "") for e in env}
            spec = WorkloadSpec.from_env({**pairs, "FOGFLEET_NODE": problem.nodes[j].node_name})
            assert spec.cpu is None
            assert spec.row.cpu == pytest.approx(problem.nominal.cpu_use[i, j])


def test_labels_owner_and_plan_annotation(catalog, problem):
    dep = render_fleet(
        problem,
        modules(catalog),
        first_allowed(problem),
        owner=Owner("warehouse", "u-1"),
        plan_id="p-42",
    )[0]
    labels = dep["metadata"]["labels"]
    assert labels["fogfleet.io/fleet"] == "warehouse"
    assert labels["fogfleet.io/robot"] == "robot-1"
    assert labels["fogfleet.io/module"] == "nav-motion-planning"
    assert labels["fogfleet.io/tier"] == "robot"
    assert labels["app.kubernetes.io/managed-by"] == "fogfleet"
    assert dep["metadata"]["annotations"][ANNOTATION_PLAN] == "p-42"
    owner = dep["metadata"]["ownerReferences"][0]
    assert (owner["kind"], owner["name"], owner["uid"], owner["controller"]) == (
        "RobotFleet",
        "warehouse",
        "u-1",
        True,
    )
    selector = dep["spec"]["selector"]["matchLabels"]
    assert all(dep["spec"]["template"]["metadata"]["labels"][k] == v for k, v in selector.items())
    assert identity_of(dep) == ("robot-1", "nav-motion-planning", 0)


def test_rendering_is_deterministic_and_the_spec_hash_ignores_the_plan_id(catalog, problem):
    p = first_allowed(problem)
    a = render_fleet(problem, modules(catalog), p, plan_id="one")
    b = render_fleet(problem, modules(catalog), p, plan_id="two")
    assert [d["metadata"]["annotations"][ANNOTATION_SPEC_HASH] for d in a] == [
        d["metadata"]["annotations"][ANNOTATION_SPEC_HASH] for d in b
    ]
    assert spec_hash(a[0]) == a[0]["metadata"]["annotations"][ANNOTATION_SPEC_HASH]


def test_a_deployment_names_its_node_outside_the_spec_hash(catalog, problem):
    """``fogfleet.io/node`` (the affinity's node, for readers of the metadata alone) is not
    hashed: adding it to an operator's Deployments restarts no pod."""
    p = first_allowed(problem)
    for dep, j in zip(render_fleet(problem, modules(catalog), p), p, strict=True):
        annotations = dep["metadata"]["annotations"]
        assert annotations[ANNOTATION_NODE] == problem.nodes[j].node_name
        assert bound_nodes(dep) == [annotations[ANNOTATION_NODE]]
        assert ANNOTATION_NODE not in dep["spec"]["template"]["metadata"]["annotations"]
        without = copy.deepcopy(dep)
        del without["metadata"]["annotations"][ANNOTATION_NODE]
        assert spec_hash(without) == annotations[ANNOTATION_SPEC_HASH]
        assert bound_nodes({"metadata": dep["metadata"]}) == bound_nodes(dep)


def test_moving_an_instance_changes_its_hash_only(catalog, problem):
    p = first_allowed(problem)
    q = p.copy()
    i = next(k for k in range(problem.n_instances) if problem.allowed[k].sum() > 1)
    q[i] = int(np.flatnonzero(problem.allowed[i])[1])
    a = render_fleet(problem, modules(catalog), p)
    b = render_fleet(problem, modules(catalog), q)
    changed = [k for k in range(len(a)) if a[k] != b[k]]
    assert changed == [i]


def test_names_are_dns_labels_unique_and_bounded():
    long = "m" * 200
    names = {
        deployment_name("fleet", Instance("a-b", "c", 0)),
        deployment_name("fleet", Instance("a", "b-c", 0)),
        deployment_name("fleet", Instance("", "svc", 0)),
        deployment_name("fleet", Instance("", "svc", 1)),
        deployment_name("f" * 100, Instance("r.1", long, 0)),
    }
    assert len(names) == 5
    for name in names:
        assert len(name) <= 57  # its pods' names begin with it (render.names)
        assert DNS_LABEL.match(name), name


def test_long_label_values_are_shortened_validly():
    value = label_value("x." * 100)
    assert len(value) <= 63
    assert re.fullmatch(r"[A-Za-z0-9]([-A-Za-z0-9_.]*[A-Za-z0-9])?", value)
    assert label_value("robot-1") == "robot-1"


def test_pods_pinned_to_a_robot_stay_while_it_is_cut_off_and_others_do_not(catalog, problem):
    """A robot's pods tolerate its node turning unreachable or not ready (no eviction: they
    have nowhere else to go), edge pods keep the cluster's eviction."""
    robots = set(np.flatnonzero(problem.tier == 0).tolist())
    x = np.array([int(np.flatnonzero(row)[-1]) for row in problem.allowed])  # edge where allowed
    deps = render_fleet(problem, modules(catalog), x)
    taints = {"node.kubernetes.io/unreachable", "node.kubernetes.io/not-ready"}
    seen = set()
    for i, dep in zip(range(problem.n_instances), deps, strict=True):
        tol = dep["spec"]["template"]["spec"].get("tolerations", [])
        forever = {
            t["key"] for t in tol
            if t.get("effect") == "NoExecute" and "tolerationSeconds" not in t
        }  # fmt: skip
        seen.add(x[i] in robots)
        assert forever == (taints if x[i] in robots else set()), dep["metadata"]["name"]
    assert seen == {True, False}


def test_a_planned_pod_plays_the_rows_it_was_planned_with_on_a_faster_node(catalog, problem):
    """On a node with ``speedFactor`` 1.25 and only 'default' rows, the planner divides every
    time by 1.25 (``domain.pairs.rows_for``); the pod must play those times, not the declared
    ones (it used to get the unscaled rows: other work than planned)."""
    speed = {name: float(n.spec.speed_factor) for name, n in catalog.nodes.items()}
    fast = [j for j, n in enumerate(problem.nodes) if speed[n.name] != 1.0]
    assert fast, "the warehouse example has nodes with speedFactor 1.25"
    placed = np.array(
        [next((j for j in fast if problem.allowed[i, j]), -1) for i in range(problem.n_instances)]
    )
    assert (placed >= 0).sum() > 0
    deps = render_fleet(problem, modules(catalog), placed)
    by_instance = {identity_of(d): d for d in deps}
    checked = 0
    for i in np.flatnonzero(placed >= 0):
        inst = problem.instances[i]
        dep = by_instance[(inst.robot, inst.module, inst.replica)]
        container = dep["spec"]["template"]["spec"]["containers"][0]
        env = {e["name"]: e.get("value", "") for e in container["env"]}
        spec = WorkloadSpec.from_env(env)
        j = int(placed[i])
        assert spec.row.mean_s == pytest.approx(problem.limits.exe_mean[i, j], rel=1e-6)
        assert spec.row.std_s == pytest.approx(problem.limits.exe_std[i, j], rel=1e-6, abs=1e-9)
        checked += 1
    assert checked == int((placed >= 0).sum())


def test_every_rendered_pod_tolerates_the_taint_of_nodes_kept_for_planned_pods(catalog, problem):
    """A node tainted ``fogfleet.io/dedicated:NoSchedule`` takes only the pods fogfleet
    rendered: planned instances on every tier, the baseline's, and no other workload."""
    x = np.array([int(np.flatnonzero(row)[-1]) for row in problem.allowed])
    planned = render_fleet(problem, modules(catalog), x)
    baseline = render_fleet(problem, modules(catalog), None, baseline=True)
    for dep in [*planned, *baseline]:
        tol = dep["spec"]["template"]["spec"]["tolerations"]
        assert {"key": "fogfleet.io/dedicated", "operator": "Exists", "effect": "NoSchedule"} in tol
