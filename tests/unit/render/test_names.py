"""Generated names are DNS labels of at most 63 characters and never collide (issue 35 item 2).

The property test renames the warehouse example's fleet, robots and modules to random long and
near-equal names (the same long prefix, differing only after character 63, or only in a dot
the cleaning turns into ``-``), renders every object a fleet gets (module Deployments, the
robots' discovery Services and Deployments, the NetworkPolicy, profiling Jobs, HPA and
ScaledObject) and checks every name and selector.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogfleet.api.loader import Catalog, load_paths
from fogfleet.api.names import dns_label, label_value
from fogfleet.api.v1alpha1.robotfleet import RosSettings
from fogfleet.api.v1alpha1.scaling import ScalingSpec
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import identity_of, render_fleet
from fogfleet.render.names import network_policy_name, profiling_job_name
from fogfleet.render.ros import discovery_servers
from fogfleet.render.scaling import render_hpa, render_scaled_object

EXAMPLES = Path(__file__).resolve().parents[3] / "manifests" / "examples"
DNS_LABEL = re.compile(r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")
LABEL_VALUE = re.compile(r"^(([A-Za-z0-9][-A-Za-z0-9_.]*)?[A-Za-z0-9])?$")


@pytest.fixture(scope="module")
def catalog() -> Catalog:
    return load_paths([EXAMPLES / "warehouse"])


@pytest.fixture(scope="module")
def problem(catalog: Catalog) -> Problem:
    return build_problem(catalog.fleets[0], catalog)


def _ok(name: str) -> None:
    assert len(name) <= 63 and DNS_LABEL.match(name), name


# Kubernetes object names (DNS subdomains): a long shared prefix, then short distinct tails.
# Built from plain alphabets: ``st.from_regex`` builds a Unicode character map on first use,
# seconds of CPU on a fresh clone with no ``.hypothesis`` cache (it failed CI's 3 s limit).
_ALNUM = "abcdefghijklmnopqrstuvwxyz0123456789"
_edge = st.sampled_from(_ALNUM)
_word = st.one_of(
    _edge,
    st.tuples(_edge, st.text(alphabet=_ALNUM + ".-", max_size=6), _edge).map("".join),
)
_prefix = st.sampled_from(["", "r", "a" * 60, "b" * 63, "c" * 64, "robot-" * 20, "x." * 40])


def _names(n: int) -> st.SearchStrategy[list[str]]:
    """``n`` distinct valid names sharing one prefix (near-equal: they differ at the end)."""
    return (
        st.tuples(_prefix, st.lists(_word, min_size=n, max_size=n, unique=True))
        .map(lambda pw: [re.sub(r"\.+", ".", f"{pw[0]}{w}").strip(".-") or "z" for w in pw[1]])
        .filter(lambda names: len(set(names)) == n)
    )


def _renamed(problem: Problem, fleet: str, robots: dict[str, str], mods: dict[str, str]) -> Problem:
    nodes = tuple(
        dataclasses.replace(nd, name=robots.get(nd.name, nd.name)) for nd in problem.nodes
    )
    instances = tuple(
        dataclasses.replace(
            inst, robot=robots.get(inst.robot, inst.robot), module=mods[inst.module]
        )
        for inst in problem.instances
    )
    return dataclasses.replace(problem, fleet=fleet, nodes=nodes, instances=instances)


@settings(
    max_examples=15,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_long_and_near_equal_names_stay_bounded_valid_and_distinct(catalog, problem, data):
    robots_old = sorted({i.robot for i in problem.instances if i.robot})
    mods_old = sorted({i.module for i in problem.instances})
    fleets = data.draw(_names(2), label="fleets")
    robots = dict(zip(robots_old, data.draw(_names(len(robots_old)), label="robots"), strict=True))
    mods = dict(zip(mods_old, data.draw(_names(len(mods_old)), label="modules"), strict=True))
    modules = {mods[n]: m for (_, n), m in catalog.modules.items() if n in mods}
    # a few instances of a few robots and modules (rendering is what takes the time)
    x = np.array(
        [
            int(np.flatnonzero(row)[0])
            if i.robot in robots_old[:3] and i.module in mods_old[:3]
            else -1
            for i, row in zip(problem.instances, problem.allowed, strict=True)
        ]
    )

    deployments: dict[str, tuple[str, str, str, int]] = {}
    services: dict[str, tuple[str, str]] = {}
    policies: dict[str, str] = {}
    for fleet in fleets:
        p = _renamed(problem, fleet, robots, mods)
        for dep in render_fleet(p, modules, x):
            name, labels = dep["metadata"]["name"], dep["metadata"]["labels"]
            _ok(name)
            _ok(dep["spec"]["template"]["spec"]["containers"][0]["name"])
            assert all(LABEL_VALUE.match(v) and len(v) <= 63 for v in labels.values()), labels
            ident = identity_of(dep)
            assert ident is not None
            assert deployments.setdefault(name, (fleet, *ident)) == (fleet, *ident)
        for robot, service, deployment in discovery_servers(p, RosSettings(), {}, []):
            name = service["metadata"]["name"]
            _ok(name)
            assert deployment["metadata"]["name"] == name
            assert services.setdefault(name, (fleet, robot)) == (fleet, robot)
            assert all(LABEL_VALUE.match(v) for v in service["spec"]["selector"].values())
        # each robot's Service selects its own robot's server only
        selectors = [
            s["spec"]["selector"] for _, s, _ in discovery_servers(p, RosSettings(), {}, [])
        ]
        assert len({tuple(sorted(s.items())) for s in selectors}) == len(selectors)
        name = network_policy_name(fleet)
        _ok(name)
        assert policies.setdefault(name, fleet) == fleet

    jobs = {profiling_job_name(m, "pi4", 0.5, "h") for m in modules}
    assert len(jobs) == len(modules)
    assert all(len(j) <= 52 and DNS_LABEL.match(j) for j in jobs)
    spec = ScalingSpec.model_validate({"minReplicas": 1, "maxReplicas": 3})
    for render in (render_hpa, render_scaled_object):
        kw = {"prometheus_url": "http://p"} if render is render_scaled_object else {}
        names = {
            render(spec, fleet="f", module=m, namespace="ns", target="t", **kw)["metadata"]["name"]
            for m in modules
        }
        assert len(names) == len(modules)
        for n in names:
            _ok(n)


def test_names_that_fit_are_kept_as_they_are():
    assert dns_label("warehouse-robot-1-dds") == "warehouse-robot-1-dds"
    assert label_value("robot.1") == "robot.1"
    assert network_policy_name("warehouse") == "warehouse-pods"
    assert profiling_job_name("detector", "pi4", 0.5, "h").startswith("detector-profile-")


def test_names_differing_after_character_63_do_not_collide():
    a, b = "r" * 70 + "-1", "r" * 70 + "-2"
    assert dns_label(f"f-{a}-dds") != dns_label(f"f-{b}-dds")
    assert label_value(a) != label_value(b)
    assert max(len(dns_label(f"f-{a}-dds")), len(label_value(a))) <= 63


def test_a_dot_the_cleaning_turns_into_a_dash_keeps_names_apart():
    assert dns_label("f-a.b-dds") != dns_label("f-a-b-dds") == "f-a-b-dds"
