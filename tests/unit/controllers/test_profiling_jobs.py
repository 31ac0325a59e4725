"""A fleet whose module has no profile for the robots' hardware: profiling Jobs first, then
the plan (issue 10, item 3)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from fogfleet.controllers.fleet.reconcile import reconcile

KEY = ("warehouse", "warehouse")
MODULE = "nav-localization"
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
