"""A fleet whose module has no profile for the robots' hardware: profiling Jobs first, then
the plan (issue 10, item 3); a split network (``spec.dnn``) declaring no time: one Job per
hardware type times its parts (issue 48, item 4)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")
MODULE = "nav-localization"
SPLIT_MODULE = "human-pose-estimation"  # as a split network (spec.dnn, issue 48 item 4)
SPLITS = ("b6", "bneck")
GRID = ["500m", "1", "2", "4"]


@pytest.fixture
def auto(kube: Any) -> Any:
    """nav-localization declares only the edge's rows and asks to be profiled elsewhere."""
    spec = kube.modules[("warehouse", MODULE)]["spec"]
    spec["profile"] = [
        {"hardwareType": hw, "cpu": "1", "meanMillis": 19, "stdMillis": 2}
        for hw in ("dsv3-16", "fsv2-8")
    ]
    spec["profiling"] = {"mode": "auto", "cpus": GRID, "cycles": 20}
    return kube


def run(kube: Any, deps: Any) -> Any:
    return reconcile(kube.get_fleet(*KEY), deps)


def ready(kube: Any) -> dict[str, Any]:
    conds = kube.fleets[KEY]["status"]["conditions"]
    return dict(next(c for c in conds if c["type"] == "Ready"))


def result(cpu: str, mean: float) -> str:
    return json.dumps(
        {
            "module": MODULE,
            "cpu": cpu,
            "cycles": 20,
            "meanMillis": mean,
            "stdMillis": mean / 10,
            "p95Millis": mean * 1.2,
            "cpuSeconds": 0.4,
            "wallSeconds": 2.5,
        }
    )


def jobs_by_cpu(kube: Any) -> dict[str, Any]:
    return {j["metadata"]["labels"]["fogfleet.io/profile-cpu"]: j for j in kube.jobs.values()}


def test_a_fleet_waits_for_its_profiles_and_touches_nothing(auto: Any, deps: Any) -> None:
    out = run(auto, deps)
    # the edge cases of the grid on the robots' hardware type, one Job each
    jobs = jobs_by_cpu(auto)
    assert sorted(jobs) == ["1000m", "4000m", "500m"]
    job = jobs["500m"]
    pod = job["spec"]["template"]["spec"]
    (container,) = pod["containers"]
    assert container["resources"]["limits"]["cpu"] == "500m"
    assert container["resources"]["requests"]["cpu"] == "500m"
    env = {e["name"]: e for e in container["env"]}
    assert env["FOGFLEET_PROFILE_CYCLES"]["value"] == "20"
    assert env["FOGFLEET_HARDWARE_TYPE"]["value"] == "robot-nuc"
    assert env["FOGFLEET_NODE"]["valueFrom"]["fieldRef"]["fieldPath"] == "spec.nodeName"
    assert "livenessProbe" not in container and pod["restartPolicy"] == "Never"
    nodes = pod["affinity"]["nodeAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"][
        "nodeSelectorTerms"
    ][0]["matchExpressions"][0]["values"]
    assert nodes == [f"robot-{k}" for k in range(1, 6)]  # the fleet's robots, all robot-nuc
    assert job["metadata"]["ownerReferences"][0]["kind"] == "SoftwareModule"
    # nothing is planned or applied; the fleet says what it waits for
    assert auto.deployments == {}
    assert ready(auto)["reason"] == "ProfilingPending"
    assert f"{MODULE} on robot-nuc" in ready(auto)["message"]
    assert out.requeue_after == 5.0
    assert ("Normal", "ProfilingPending") in [(t, r) for t, r, _ in auto.events]
    # a second pass creates nothing twice and says it once
    events = len(auto.events)
    run(auto, deps)
    assert len(auto.jobs) == 3 and len(auto.events) == events


def test_finished_jobs_give_the_profile_and_the_fleet_is_planned(auto: Any, deps: Any) -> None:
    run(auto, deps)
    # 10 ms + 15 ms/c, measured at 0.5, 1 and 4 cores
    for cpu, job in jobs_by_cpu(auto).items():
        cores = int(cpu[:-1]) / 1000
        auto.finish_job("warehouse", job["metadata"]["name"], result(cpu, 10 + 15 / cores))
    run(auto, deps)
    prof = auto.modules[("warehouse", MODULE)]["status"]["profiling"]
    (r,) = prof["runs"]
    assert r["state"] == "Profiled" and r["jobs"] == 3 and r["grid"] == 4
    assert r["cpuSeconds"] == pytest.approx(1.2) and r["fitErrorPercent"] == pytest.approx(0)
    assert "predicted from the ends 0 % off" in r["message"]
    rows = {row["cpu"]: row for row in prof["rows"]}
    assert rows["2000m"]["source"] == "fitted"
    assert rows["2000m"]["meanMillis"] == pytest.approx(17.5)
    assert rows["500m"]["source"] == "measured" and rows["500m"]["meanMillis"] == 40
    assert auto.jobs == {}  # recorded: the Jobs are gone
    assert any(reason == "Profiled" for _, reason, _ in auto.events)
    # planned in the same pass, the localizer placed with a robot row if on board
    assert auto.deployments
    assert ready(auto)["reason"] != "ProfilingPending"
    placed = [p for p in auto.fleets[KEY]["status"]["placement"] if p["module"] == MODULE]
    assert len(placed) == 5
    # and the next passes neither profile again nor wait
    run(auto, deps)
    assert auto.jobs == {}


def test_a_failed_job_fails_the_run_with_the_pods_words(auto: Any, deps: Any) -> None:
    run(auto, deps)
    name = jobs_by_cpu(auto)["500m"]["metadata"]["name"]
    auto.finish_job("warehouse", name, "fogfleet-workload: no work to profile", ok=False)
    out = run(auto, deps)
    (r,) = auto.modules[("warehouse", MODULE)]["status"]["profiling"]["runs"]
    assert r["state"] == "Failed" and "no work to profile" in r["message"]
    assert ready(auto)["reason"] == "ProfilingFailed"
    assert "no work to profile" in ready(auto)["message"]
    assert out.requeue_after is None  # nothing to wait for but the user
    assert ("Warning", "ProfilingFailed") in [(t, r) for t, r, _ in auto.events]
    # a new container profiles again
    auto.modules[("warehouse", MODULE)]["spec"]["template"]["args"] = ["--cpu-work", "5"]
    run(auto, deps)
    assert ready(auto)["reason"] == "ProfilingPending"
    assert len(auto.jobs) == 6  # three new ones beside the failed run's (they expire)


@pytest.fixture
def split(kube: Any) -> Any:
    """The warehouse's pose estimator as a split network whose times are to be measured."""
    spec = kube.modules[("warehouse", SPLIT_MODULE)]["spec"]
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
    prof = split.modules[("warehouse", SPLIT_MODULE)]["status"]["profiling"]
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
    placed = [p for p in split.fleets[KEY]["status"]["placement"] if p["module"] == SPLIT_MODULE]
    assert placed and all(p.get("split", {}).get("action") for p in placed)
    heads = [
        d for d in split.deployments.values()
        if d["metadata"]["labels"].get("fogfleet.io/module") == SPLIT_MODULE
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
