"""A split network (``spec.dnn``) with ``profiling.mode: auto`` declares no time: one Job per
hardware type times its parts, and the fleet is planned with what they measured (issue 48,
item 4)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")
HPE = "human-pose-estimation"
SPLITS = ("b6", "bneck")


@pytest.fixture
def split(kube: Any) -> Any:
    """The warehouse's pose estimator as a split network whose times are to be measured."""
    spec = kube.modules[("warehouse", HPE)]["spec"]
    spec.pop("profile")
    spec.pop("fallback", None)
    spec["dnn"] = {
        "minAccuracy": 0.8,
        "accuracy": 0.92,
        "splitPoints": [{"name": n} for n in SPLITS],
        "localModel": {"name": "tiny", "accuracy": 0.61},
    }
    spec["profiling"] = {"mode": "auto", "cycles": 30}
    return kube


def run(kube: Any, deps: Any) -> Any:
    return reconcile(kube.get_fleet(*KEY), deps)


def ready(kube: Any) -> dict[str, Any]:
    conds = kube.fleets[KEY]["status"]["conditions"]
    return dict(next(c for c in conds if c["type"] == "Ready"))


def measured(hw: str) -> str:
    """A Job's result line (``contract.dnn``): a robot computes 10x slower than an edge."""
    slow = 10.0 if hw.startswith("robot") else 1.0
    parts = {
        "inputBytes": 602112,
        "outputBytes": 4000,
        "fullMillis": 4.0 * slow,
        "localMillis": 0.5 * slow,
        "splitPoints": [
            {"name": "b6", "headMillis": 2.0 * slow, "tailMillis": 1.5 * slow,
             "tensorBytes": 401408},
            {"name": "bneck", "headMillis": 2.1 * slow, "tailMillis": 1.4 * slow,
             "tensorBytes": 6272},
        ],
    }  # fmt: skip
    line = {"cycles": 30, "meanMillis": 4.0 * slow, "stdMillis": 0.1, "cpuSeconds": 0.9,
            "wallSeconds": 1.2, "dnn": parts}  # fmt: skip
    return json.dumps(line)


def test_one_job_per_hardware_type_times_the_network_and_the_fleet_is_planned_with_it(
    split: Any, deps: Any
) -> None:
    run(split, deps)
    assert ready(split)["reason"] == "ProfilingPending"
    assert split.deployments == {}
    jobs = list(split.jobs.values())
    types = {j["metadata"]["labels"]["fogfleet.io/profile-hardware-type"] for j in jobs}
    assert len(jobs) == len(types) >= 2  # one Job per type: robots' and off-board ones
    assert any(t.startswith("robot") for t in types)
    for job in jobs:
        (container,) = job["spec"]["template"]["spec"]["containers"]
        cpu = container["resources"]["limits"]["cpu"]
        assert cpu == "1000m" or int(cpu[:-1]) < 1000  # one thread: one core at most
        env = {e["name"]: e.get("value") for e in container["env"]}
        spec = json.loads(env["FOGFLEET_MODULE_SPEC"])
        assert spec["dnnProfile"] == {"splitPoints": list(SPLITS)}
        assert "dnn" not in spec  # no times to run with: the Job only measures
        assert env["FOGFLEET_PROFILE_CYCLES"] == "30"
    for job in jobs:
        hw = job["metadata"]["labels"]["fogfleet.io/profile-hardware-type"]
        split.finish_job("warehouse", job["metadata"]["name"], measured(hw))
    run(split, deps)
    prof = split.modules[("warehouse", HPE)]["status"]["profiling"]
    assert {r["state"] for r in prof["runs"]} == {"Profiled"}
    by_type = {p["hardwareType"]: p for p in prof["dnn"]}
    assert set(by_type) == types
    robot = next(p for t, p in by_type.items() if t.startswith("robot"))
    assert robot["splitPoints"][1] == {
        "name": "bneck", "headMillis": 21.0, "tailMillis": 14.0, "tensorBytes": 6272
    }  # fmt: skip
    assert robot["frames"] == 30
    assert split.jobs == {}
    assert any(reason == "Profiled" for _, reason, _ in split.events)
    # planned with the measured times: every pose estimator's tail off board with a split
    assert ready(split)["reason"] != "ProfilingPending"
    placed = [p for p in split.fleets[KEY]["status"]["placement"] if p["module"] == HPE]
    assert placed and all(p.get("split", {}).get("action") for p in placed)
    heads = [
        d for d in split.deployments.values()
        if d["metadata"]["labels"].get("fogfleet.io/module") == HPE
    ]  # fmt: skip
    assert heads
    env = {
        e["name"]: e.get("value")
        for d in heads
        for e in d["spec"]["template"]["spec"]["containers"][0]["env"]
        if e["name"] == "FOGFLEET_MODULE_SPEC"
    }
    dnn = json.loads(env["FOGFLEET_MODULE_SPEC"])["dnn"]
    # the pods run with the times measured where they run (robot side: factor 1)
    assert dnn["robotFactor"] == 1.0
    assert dnn["splitPoints"][1]["headMillis"] == pytest.approx(21.0)
    # the next pass profiles nothing again
    run(split, deps)
    assert split.jobs == {}
