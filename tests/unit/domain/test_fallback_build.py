"""Which instances keep a fallback and the row their standby runs with (issue 13)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fogfleet.api.loader import load_paths
from fogfleet.api.v1alpha1.fallback import Fallback, FallbackMode
from fogfleet.domain.build import build_problem
from fogfleet.domain.problem import Problem
from fogfleet.render.deployments import render_fleet
from fogfleet.scheduling.evaluation import Evaluation
from fogfleet.scheduling.fallback import disconnected

WAREHOUSE = Path(__file__).resolve().parents[3] / "manifests" / "examples" / "warehouse"
HPE = "human-pose-estimation"


def _problem(cpu: str | None) -> tuple[Problem, dict[str, object]]:
    catalog = load_paths([WAREHOUSE])
    (fleet,) = catalog.fleets
    for key, m in list(catalog.modules.items()):
        if key[1] == HPE:
            fb = Fallback(mode=FallbackMode.ONBOARD, cpu=cpu)
            catalog.modules[key] = m.model_copy(
                update={"spec": m.spec.model_copy(update={"fallback": fb})}
            )
    mods = {name: m for (_, name), m in catalog.modules.items()}
    return build_problem(fleet, catalog), mods


def test_a_lighter_standby_holds_less_and_the_module_on_board_still_gets_its_share() -> None:
    full, _ = _problem(None)
    light, _ = _problem("1")
    rows = [i for i, inst in enumerate(light.instances) if inst.module == HPE]
    i, h = rows[0], int(light.home[rows[0]])
    pick = float(light.limits.cpu_request[i, h])
    assert pick > 1.0  # the module's own on-board share is larger than the standby's
    assert full.fallback_reserve(full.limits)[h, 0] == pytest.approx(pick)
    assert light.fallback_reserve(light.limits)[h, 0] == pytest.approx(1.0)
    assert light.fallback_row[i, 0] == pytest.approx(1.0)
    # its robot's load: the module's full share on board, the standby's 1 core off board
    edge = int(np.flatnonzero(light.allowed[i] & (light.tier == 1))[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in light.allowed])
    x[i] = h
    on = Evaluation(light, x[None, :], light.limits).cpu_requested[0, h]
    x[i] = edge
    off = Evaluation(light, x[None, :], light.limits).cpu_requested[0, h]
    assert on - off == pytest.approx(pick - 1.0)


def test_a_standby_cpu_below_every_profiled_row_takes_the_smallest() -> None:
    tiny, _ = _problem("10m")
    rows = [i for i, inst in enumerate(tiny.instances) if inst.module == HPE]
    assert tiny.fallback_row is not None
    smallest = tiny.fallback_row[rows[0], 0]
    assert 0.01 < smallest <= 1.0  # the smallest profiled CPU of the robot's hardware


def test_the_standby_runs_the_lighter_row_and_the_cut_robot_misses_more() -> None:
    light, mods = _problem("1")
    full, _ = _problem(None)
    rows = [i for i, inst in enumerate(light.instances) if inst.module == HPE]
    i = rows[0]
    edge = int(np.flatnonzero(light.allowed[i] & (light.tier == 1))[0])
    x = np.array([int(np.flatnonzero(r)[0]) for r in light.allowed])
    x[i] = edge
    deps = render_fleet(
        light, mods, x, fallbacks={HPE: Fallback(mode=FallbackMode.ONBOARD, cpu="1")}
    )
    (standby,) = [
        d for d in deps if d["metadata"]["annotations"].get("fogfleet.io/role") == "standby"
    ]
    (container,) = standby["spec"]["template"]["spec"]["containers"]
    assert container["resources"]["requests"]["cpu"] == "1000m"
    env = {e["name"]: e.get("value") for e in container["env"]}
    assert env["FOGFLEET_CPU"] == "1000m" and env["FOGFLEET_ROLE"] == "standby"
    robot = light.nodes[int(light.home[i])].name
    cut_light = {c.robot: c for c in disconnected(light, x)}[robot]
    cut_full = {c.robot: c for c in disconnected(full, x)}[robot]
    assert cut_light.standbys == cut_full.standbys == (HPE,)
    # one core instead of its own share: it misses more while the robot is cut off
    assert cut_light.miss_rate > cut_full.miss_rate + 0.01
