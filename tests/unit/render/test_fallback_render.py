"""Rendering an offloaded module with an on-board fallback: the remote instance and its
standby on the robot (issue 13)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
from fogfleet.domain.build import build_problem
from fogfleet.domain.fallback import fleet_fallbacks
from fogfleet.render.deployments import format_cpu, identity_of, render_fleet
from fogfleet.workload.fallback import Role
from fogfleet.workload.spec import WorkloadSpec

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
MODULE = "human-pose-estimation"


def _env(dep: dict[str, Any]) -> dict[str, str]:
    (container,) = dep["spec"]["template"]["spec"]["containers"]
    return {e["name"]: e.get("value", "") for e in container["env"]}


def _node(dep: dict[str, Any]) -> str:
    terms = dep["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
        "requiredDuringSchedulingIgnoredDuringExecution"
    ]["nodeSelectorTerms"]
    value: str = terms[0]["matchExpressions"][0]["values"][0]
    return value


def test_an_offloaded_fallback_gets_a_standby_on_its_robot_and_an_onboard_one_does_not() -> None:
    catalog = load_paths([WAREHOUSE])
    (fleet,) = catalog.fleets
    spec = fleet.spec.model_copy(
        update={"fallback": Fallback(mode=FallbackMode.ONBOARD, silent_cycles=4)}
    )
    fleet = fleet.model_copy(update={"spec": spec})
    modules = {name: m for (_, name), m in catalog.modules.items()}
    problem = build_problem(fleet, catalog)
    fallbacks = fleet_fallbacks(fleet.spec, modules)
    assert MODULE in fallbacks and "nav-controller" not in fallbacks  # critical: on board
    rows = [i for i, inst in enumerate(problem.instances) if inst.module == MODULE]
    assert problem.held_at_home[rows].all()
    # the first robot's instance offloaded to the first edge node, the second's on board
    edge = int(np.flatnonzero(problem.tier == 1)[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in problem.allowed])
    off, on = rows[0], rows[1]
    x[off], x[on] = edge, problem.home[on]
    deps = render_fleet(problem, modules, x, fallbacks=fallbacks)
    assert len(deps) == problem.n_instances + 1  # one standby

    mine = [d for d in deps if d["metadata"]["annotations"]["fogfleet.io/module"] == MODULE]
    robot = problem.instances[off].robot
    remote, standby = (
        [d for d in mine if d["metadata"]["annotations"]["fogfleet.io/robot"] == robot]
    )  # fmt: skip
    home = problem.nodes[int(problem.home[off])].node_name
    assert _node(remote) == problem.nodes[edge].node_name and _node(standby) == home
    assert identity_of(remote) == (robot, MODULE, 0) and identity_of(standby) is None
    assert standby["metadata"]["name"] != remote["metadata"]["name"]
    assert standby["metadata"]["labels"]["app.kubernetes.io/component"] == "fallback-standby"
    # the standby requests exactly what the planner reserved on the robot
    requests = standby["spec"]["template"]["spec"]["containers"][0]["resources"]["requests"]
    reserve = problem.limits.cpu_request[off, problem.home[off]]
    assert requests["cpu"] == format_cpu(float(reserve))
    # the workload reads its role and windows from what was rendered
    for dep, role in ((remote, Role.REMOTE), (standby, Role.STANDBY)):
        ws = WorkloadSpec.from_env(_env(dep))
        assert (ws.role, ws.silent_cycles, ws.step_back_cycles) == (role, 4, 10)
    assert json.loads(_env(standby)["FOGFLEET_MODULE_SPEC"])["fallback"]["silentCycles"] == 4
    # on board: one Deployment, no role (its environment is that of a fleet without fallbacks)
    (onboard,) = [
        d
        for d in mine
        if d["metadata"]["annotations"]["fogfleet.io/robot"] == problem.instances[on].robot
    ]
    assert "FOGFLEET_ROLE" not in _env(onboard)
    assert "fallback" not in json.loads(_env(onboard)["FOGFLEET_MODULE_SPEC"])
