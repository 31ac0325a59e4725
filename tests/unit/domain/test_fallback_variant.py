"""A standby that runs a lighter variant module (fallback mode variant, issue 13)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fogfleet.api.loader import Catalog, load_paths, parse_object
from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
from fogfleet.domain.build import build_problem
from fogfleet.domain.fallback import fleet_fallbacks
from fogfleet.domain.problem import Problem
from fogfleet.errors import DanglingReference, InvalidSpec
from fogfleet.render.deployments import render_fleet
from fogfleet.scheduling.evaluation import Evaluation
from fogfleet.scheduling.fallback import disconnected

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
HPE = "human-pose-estimation"
LITE = "human-pose-lite"


def _catalog(
    lite: dict[str, Any] | None = None, robot_rows: bool = True
) -> tuple[Catalog, dict[str, Any]]:
    """The warehouse with HPE falling back to LITE: a 200 ms variant at a quarter core."""
    catalog = load_paths([WAREHOUSE])
    key = next(k for k in catalog.modules if k[1] == HPE)
    hpe = catalog.modules[key]
    if lite is None:
        lite = json.loads(hpe.model_dump_json(by_alias=True, exclude_none=True))
        lite["metadata"] = {"name": LITE, "namespace": key[0]}
        lite["spec"].pop("fallback", None)
        lite["spec"]["template"]["image"] = "example.org/hpe-lite:1"
        lite["spec"]["cycleTimeMillis"] = 200
        lite["spec"]["resources"] = {"cpu": "250m", "memory": "256Mi"}
        hw = {n.spec.hardware_type for n in catalog.nodes.values() if n.spec.tier.value == "robot"}
        lite["spec"]["profile"] = [
            {"hardwareType": h, "cpu": "250m", "meanMillis": 150, "stdMillis": 6}
            for h in (sorted(hw) if robot_rows else ["some-gpu-box"])
        ]
    catalog.add(parse_object(copy.deepcopy(lite)))  # type: ignore[arg-type]
    fb = Fallback(mode=FallbackMode.VARIANT, variant=str(lite["metadata"]["name"]))
    catalog.modules[key] = hpe.model_copy(
        update={"spec": hpe.spec.model_copy(update={"fallback": fb})}
    )
    return catalog, lite


def _problem(**kw: Any) -> tuple[Problem, Catalog]:
    catalog, _ = _catalog(**kw)
    (fleet,) = catalog.fleets
    return build_problem(fleet, catalog), catalog


def _rows(problem: Problem) -> list[int]:
    return [i for i, inst in enumerate(problem.instances) if inst.module == HPE]


def test_the_robot_holds_the_variants_row_not_the_modules_share() -> None:
    p, _ = _problem()
    i = _rows(p)[0]
    h = int(p.home[i])
    assert p.standing_by[i] and not p.held_at_home[i]
    assert p.fallback_variant is not None and p.fallback_variant[i]
    assert p.fallback_row is not None and p.fallback_row[i, 0] == pytest.approx(0.25)
    assert p.fallback_cycle is not None and p.fallback_cycle[i] == pytest.approx(0.2)
    assert p.fallback_need is not None and p.fallback_need[i, 0] == 256 * 2**20
    assert p.fallback_reserve(p.limits)[h, 0] == pytest.approx(0.25)
    # on board the module needs its whole share on top of the variant's reserve (the
    # variant does not run then, but the robot holds its share whatever the plan)
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in p.allowed])
    x[i] = h
    on = Evaluation(p, x[None, :], p.limits).cpu_requested[0, h]
    x[i] = edge
    off = Evaluation(p, x[None, :], p.limits).cpu_requested[0, h]
    assert on - off == pytest.approx(float(p.limits.cpu_request[i, h]))


def test_the_standby_runs_the_variants_container_for_the_module() -> None:
    p, catalog = _problem()
    (fleet,) = catalog.fleets
    mods = {name: m for (_, name), m in catalog.modules.items()}
    i = _rows(p)[0]
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in p.allowed])
    x[i] = edge
    deps = render_fleet(p, mods, x, fallbacks=fleet_fallbacks(fleet.spec, mods))
    (standby,) = [
        d for d in deps if d["metadata"]["annotations"].get("fogfleet.io/role") == "standby"
    ]
    assert standby["metadata"]["labels"]["fogfleet.io/module"] == HPE
    assert standby["spec"]["template"]["spec"]["affinity"] is not None
    (container,) = standby["spec"]["template"]["spec"]["containers"]
    assert container["image"] == "example.org/hpe-lite:1"
    assert container["resources"]["requests"] == {"cpu": "250m", "memory": str(256 * 2**20)}
    env = {e["name"]: e.get("value") for e in container["env"]}
    assert env["FOGFLEET_MODULE"] == HPE and env["FOGFLEET_VARIANT"] == LITE
    assert env["FOGFLEET_ROLE"] == "standby" and env["FOGFLEET_CPU"] == "250m"
    spec = json.loads(env["FOGFLEET_MODULE_SPEC"])
    assert spec["cycleTimeMillis"] == 200
    hpe_cycle = catalog.modules[next(k for k in catalog.modules if k[1] == HPE)].spec
    assert spec["fallback"]["remoteCycleTimeMillis"] == pytest.approx(
        float(hpe_cycle.cycle_time_millis)
    )
    # the remote instance is the module's own
    (remote,) = [
        c
        for d in deps
        for c in d["spec"]["template"]["spec"]["containers"]
        if {"name": "FOGFLEET_ROLE", "value": "remote"} in c["env"]
    ]
    assert remote["image"] != "example.org/hpe-lite:1"


def test_a_cut_robot_runs_the_variant_at_its_own_cycle() -> None:
    p, _ = _problem()
    i = _rows(p)[0]
    edge = int(np.flatnonzero(p.allowed[i] & (p.tier == 1))[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in p.allowed])
    x[i] = edge
    robot = p.nodes[int(p.home[i])].name
    cut = next(c for c in disconnected(p, x) if c.robot == robot)
    assert HPE in cut.standbys and cut.reserved_cpu == pytest.approx(0.25)
    # 150 ms on a quarter core: it keeps its 200 ms cycles (it would miss the module's 100 ms)
    assert cut.miss_rate < 1.0 / len({inst.module for inst in p.instances if inst.robot == robot})


def test_a_variant_without_a_row_for_the_robot_is_refused_by_name() -> None:
    catalog, _ = _catalog(robot_rows=False)
    (fleet,) = catalog.fleets
    with pytest.raises(InvalidSpec) as err:
        build_problem(fleet, catalog)
    assert err.value.field == "spec.fallback.variant"
    assert f"{LITE} has no profile row for hardware type" in err.value.message


def test_a_missing_variant_is_a_dangling_reference() -> None:
    catalog, _ = _catalog()
    (fleet,) = catalog.fleets
    del catalog.modules[next(k for k in catalog.modules if k[1] == LITE)]
    with pytest.raises(DanglingReference, match=f"{LITE} does not exist"):
        build_problem(fleet, catalog)


def test_a_variant_must_publish_what_the_module_publishes() -> None:
    catalog, _ = _catalog()
    (fleet,) = catalog.fleets
    key = next(k for k in catalog.modules if k[1] == LITE)
    spec = catalog.modules[key].spec
    catalog.modules[key] = catalog.modules[key].model_copy(
        update={
            "spec": spec.model_copy(
                update={"topics": spec.topics.model_copy(update={"publishes": []})}
            )
        }
    )
    with pytest.raises(InvalidSpec, match=f"{LITE} does not publish"):
        build_problem(fleet, catalog)
