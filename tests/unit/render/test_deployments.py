"""Rendering plans into Deployments: names, affinity, resources, labels, owner, idempotence."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import Catalog, load_paths
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Instance, Problem
from fogfleet.render.deployments import (
    ANNOTATION_PLAN,
    ANNOTATION_SPEC_HASH,
    Owner,
    deployment_name,
    format_cpu,
    identity_of,
    label_value,
    render_fleet,
    spec_hash,
)
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
        assert len(name) <= 63
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
