"""The `fogfleet` command on the examples and on bad input (exit codes, messages, JSON shape)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.commandline.cli import main
from fogfleet.render.names import discovery_service_name

ROOT = Path(__file__).resolve().parents[4]
WAREHOUSE = ROOT / "manifests" / "examples" / "warehouse"
SOLO = ROOT / "manifests" / "examples" / "single-robot"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_plan_json_places_every_instance_on_an_allowed_node(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = run(
        capsys, "plan", str(WAREHOUSE), "--json", "--generations", "15", "--seed", "3"
    )
    assert code == 0
    doc = json.loads(out)
    assert doc["feasible"] is True
    assert {"placement", "objectives", "feasible", "durationSeconds"} <= doc.keys()
    assert len(doc["placement"]) == 40
    for row in doc["placement"]:
        # hard real-time / safety-critical and lidar-bound modules stay on their own robot
        if row["module"] in ("nav-controller", "nav-localization"):
            assert row["node"] == row["robot"]
        # never another robot's computer
        if row["tier"] == "robot":
            assert row["node"] == row["robot"]
    assert set(doc["objectives"]) >= {"onboard", "reserve", "balance", "missedCycles", "missRate"}


def test_plan_prints_a_table_and_the_choice(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "plan", str(SOLO), "--generations", "10")
    assert code == 0
    assert "ROBOT" in out and "solo-robot" in out and "Choice:" in out


def test_simulate_all_compares_three_schedulers(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(
        capsys,
        "simulate",
        str(WAREHOUSE),
        "--scheduler",
        "all",
        "--duration",
        "10",
        "--generations",
        "10",
        "--json",
    )
    assert code == 0
    doc = json.loads(out)
    assert set(doc) == {"nsga2", "k8s-default", "onboard"}
    for result in doc.values():
        assert 0.0 <= result["missRate"] <= 1.0
        assert "human-pose-estimation" in result["modules"]
    # everything on the 6 usable cores of each robot saturates them (paper IV-A)
    assert doc["onboard"]["missRate"] > doc["nsga2"]["missRate"]


def test_simulate_reads_back_a_saved_placement(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, _ = run(capsys, "plan", str(WAREHOUSE), "--scheduler", "onboard", "--json")
    assert code == 0
    saved = tmp_path / "plan.json"
    saved.write_text(out)
    code, out, _ = run(
        capsys,
        "simulate",
        str(WAREHOUSE),
        "--scheduler",
        "onboard",
        "--placement",
        str(saved),
        "--duration",
        "10",
        "--json",
    )
    assert code == 0
    doc = json.loads(out)
    # the same placement, simulated with the same seed, gives the same figure
    assert doc["recorded"]["missRate"] == pytest.approx(doc["onboard"]["missRate"])


def test_render_binds_each_deployment_to_its_node(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "render", str(WAREHOUSE), "--scheduler", "onboard")
    assert code == 0
    docs = [d for d in yaml.safe_load_all(out) if d]
    modules = [d for d in docs if "fogfleet.io/module" in d["metadata"]["labels"]]
    assert len(modules) == 40 and all(d["kind"] == "Deployment" for d in modules)
    for d in modules:
        terms = d["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        values = terms[0]["matchExpressions"][0]["values"]
        assert values == [d["metadata"]["labels"]["fogfleet.io/robot"]]
        # onboard is planned for the nominal allocation, and so it runs: no limits (as the
        # simulator has it); a pinned pod still learns its node from the downward API
        assert "limits" not in d["spec"]["template"]["spec"]["containers"][0]["resources"]
    # the ROS wiring is visible: one discovery server (Service + Deployment) per robot
    others = [d for d in docs if d not in modules]
    kinds = sorted(d["kind"] for d in others)
    # the fleet's, its metrics', the shared services' and one NetworkPolicy per robot
    assert kinds == ["Deployment"] * 5 + ["NetworkPolicy"] * 8 + ["Service"] * 5
    env = {
        e["name"]: e.get("value", "")
        for e in modules[0]["spec"]["template"]["spec"]["containers"][0]["env"]
    }
    robot = modules[0]["metadata"]["labels"]["fogfleet.io/robot"]
    server = discovery_service_name("warehouse", robot)
    assert env["ROS_DISCOVERY_SERVER"] == f"{server}.warehouse.svc:11811"


def _fleet(tmp_path: Path, spec: str) -> Path:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        "apiVersion: fogfleet.io/v1alpha1\nkind: RobotFleet\n"
        "metadata: {name: bad, namespace: warehouse}\n" + spec
    )
    return path


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (
            "spec:\n  robots: [robot-9]\n  modules: [{name: nav-controller}]\n",
            "RobotFleet/bad: spec.robots[0]: ComputeNode 'robot-9' does not exist",
        ),
        (
            "spec:\n  robots: [robot-1]\n  modules: [{name: no-such-module}]\n",
            "RobotFleet/bad: spec.modules[0].name: "
            "SoftwareModule warehouse/no-such-module does not exist",
        ),
        (
            "spec:\n  robots: [robot-1]\n  modules: [{name: nav-controller, colour: red}]\n",
            "RobotFleet/bad: spec.modules[0].colour: unknown field",
        ),
        (
            "spec:\n  robots: [robot-1]\n  modules: [{name: nav-controller}]\n"
            "  scheduler: {population: many}\n",
            "RobotFleet/bad: spec.scheduler.population",
        ),
        (
            "spec:\n  robots: [robot-1]\n  modules: [{name: nav-controller}]\n"
            "  scheduler: {algorithm: best}\n",
            "RobotFleet/bad: spec.scheduler.algorithm",
        ),
        (
            "spec:\n  modules: [{name: nav-controller}]\n",
            "RobotFleet/bad: spec.robots: list at least one robot or set robotSelector",
        ),
    ],
)
def test_bad_fleets_exit_2_naming_object_and_field(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, spec: str, message: str
) -> None:
    fleet = _fleet(tmp_path, spec)
    code, _, err = run(
        capsys, "plan", str(WAREHOUSE / "nodes.yaml"), str(WAREHOUSE / "modules.yaml"), str(fleet)
    )
    assert code == 2
    assert message in err


def test_a_module_that_fits_nowhere_is_reported_with_the_reason(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    modules = (
        (WAREHOUSE / "modules.yaml")
        .read_text()
        .replace(
            '  resources: {cpu: "250m", memory: 512Mi}\n  requirements: {devices: [lidar]}',
            '  resources: {cpu: "250m", memory: 512Mi, gpu: 1}\n'
            "  requirements: {devices: [lidar], gpu: true}",
        )
    )
    (tmp_path / "modules.yaml").write_text(modules)
    (tmp_path / "nodes.yaml").write_text((WAREHOUSE / "nodes.yaml").read_text())
    (tmp_path / "fleet.yaml").write_text((WAREHOUSE / "fleet.yaml").read_text())
    code, out, _ = run(capsys, "plan", str(tmp_path), "--scheduler", "onboard", "--json")
    assert code == 2
    doc = json.loads(out)
    assert doc["feasible"] is False
    why = doc["unplaced"]["robot-1/nav-localization"]
    assert "no GPU" in why and "robot-1" in why


def test_crds_check_passes_on_the_committed_crds(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "crds", "--check", str(ROOT / "crds"))
    assert code == 0 and "match" in out


@pytest.mark.integration
def test_plot_writes_a_png(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = tmp_path / "plan.png"
    code, _, _ = run(capsys, "plan", str(WAREHOUSE), "--generations", "5", "--plot", str(out))
    assert code == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


def test_all_active_reproduces_the_papers_overloaded_robot(
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = ("simulate", str(WAREHOUSE), "--scheduler", "onboard", "--duration", "10", "--json")
    _, rates, _ = run(capsys, *args)
    _, busy, _ = run(capsys, *args, "--all-active")
    # IV-B: every module active at once saturates the 6 on-board cores far more often
    assert json.loads(busy)["onboard"]["missRate"] > 2 * json.loads(rates)["onboard"]["missRate"]


def _short_site(tmp_path: Path, *, allow_degraded: bool = False) -> Path:
    """The single-robot fleet with a 1-core edge node: nothing fits as planned (and, unless
    ``allow_degraded``, the fleet forbids running its modules below their deadline's CPU)."""
    nodes = (
        (SOLO / "nodes.yaml")
        .read_text()
        .replace("capacity: {cpu: 16, memory: 64Gi}", "capacity: {cpu: 1, memory: 64Gi}")
    )
    assert "cpu: 1," in nodes
    (tmp_path / "nodes.yaml").write_text(nodes)
    fleet = (SOLO / "fleet.yaml").read_text()
    if not allow_degraded:
        fleet = fleet.replace("  modules:\n", "  scheduler: {allowDegraded: false}\n  modules:\n")
        assert "allowDegraded" in fleet
    (tmp_path / "fleet.yaml").write_text(fleet)
    (tmp_path / "modules.yaml").write_text((SOLO / "modules.yaml").read_text())
    return tmp_path


def test_render_refuses_a_fleet_that_cannot_run_as_planned(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    site = _short_site(tmp_path)
    code, out, err = run(capsys, "render", str(site), "--generations", "5")
    assert code == 2 and out == ""
    assert "cannot run as planned" in err and "over by" in err and "--allow-unplaced" in err
    code, out, _ = run(capsys, "render", str(site), "--generations", "5", "--allow-unplaced")
    assert code == 0 and "kind: Deployment" in out


def test_simulate_says_infeasible_and_names_the_worst_module(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    site = _short_site(tmp_path)
    code, out, err = run(capsys, "simulate", str(site), "--duration", "5", "--generations", "5")
    assert code == 2
    assert "INFEASIBLE nsga2: no placement fits" in err
    worst = next(line for line in out.splitlines() if line.startswith("WORST MODULE"))
    assert "%" in worst or "UNPLACED" in worst


def test_a_short_site_plans_degraded_with_a_warning_and_exit_0(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    (tmp_path / "site").mkdir()
    site = _short_site(tmp_path / "site", allow_degraded=True)
    code, out, err = run(capsys, "plan", str(site), "--json", "--generations", "5")
    doc = json.loads(out)
    assert code == 0 and doc["feasible"] is True and doc["degraded"] is True
    assert err.startswith(
        "DEGRADED single-robot/single-robot: degraded: the nodes are short of CPU"
    )
    below = [r for r in doc["placement"] if "cpuForDeadline" in r]
    assert below and all(r["cpu"] < r["cpuForDeadline"] for r in below)
    assert all(r["module"] != "nav-controller" for r in below), "hard real-time keeps its CPU"
    assert "predicted miss" in doc["degradedReason"]
    # the saved degraded plan simulates with the CPU it was given, as nsga2 does
    saved = tmp_path / "plan.json"  # beside the site's folder: a plan is not a CR
    saved.write_text(out)
    args = ("simulate", str(site), "--duration", "10", "--generations", "5", "--json")
    code, out, _ = run(capsys, *args, "--placement", str(saved))
    sim = json.loads(out)
    assert code == 0
    assert sim["recorded"]["missRate"] == pytest.approx(sim["nsga2"]["missRate"])
    code, out, _ = run(capsys, "render", str(site), "--generations", "5")
    resources = [
        d["spec"]["template"]["spec"]["containers"][0]["resources"]
        for d in yaml.safe_load_all(out)
        if d and d.get("kind") == "Deployment" and "fogfleet.io/module" in d["metadata"]["labels"]
    ]
    # degraded modules request the guaranteed CPU and may burst to their deadline's (with the
    # default headroom of 200 %, beyond twice their request)
    burst = [
        r for r in resources if parse_cpu(r["limits"]["cpu"]) > 2 * parse_cpu(r["requests"]["cpu"])
    ]
    assert code == 0 and len(burst) == len(below)


def test_the_fleet_level_reason_is_not_pinned_on_an_instance(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    site = _short_site(tmp_path)
    code, out, _ = run(capsys, "plan", str(site), "--json", "--generations", "5")
    doc = json.loads(out)
    assert code == 2 and doc["feasible"] is False
    labels = set(doc["unplaced"])
    assert labels <= {"fleet"} | {f"solo-robot/{r['module']}" for r in doc["placement"]}
    if "fleet" in labels:  # the solver's fleet-level reason, not the last instance's
        assert all(r["node"] for r in doc["placement"] if f"solo-robot/{r['module']}" in labels)
    assert "no placement fits" in doc["infeasible"]


def test_a_gpu_requirement_without_a_gpu_request_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    modules = (WAREHOUSE / "modules.yaml").read_text()
    modules = modules.replace(
        "  requirements: {devices: [lidar]}", "  requirements: {devices: [lidar], gpu: true}"
    )
    (tmp_path / "modules.yaml").write_text(modules)
    code, _, err = run(
        capsys, "plan", str(WAREHOUSE / "nodes.yaml"), str(tmp_path), str(WAREHOUSE / "fleet.yaml")
    )
    assert code == 2
    assert "spec.resources.gpu: requirements.gpu is true but no GPU is requested" in err


def test_an_object_defined_in_two_files_is_refused_naming_both(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    (tmp_path / "a.yaml").write_text((WAREHOUSE / "nodes.yaml").read_text())
    (tmp_path / "b.yaml").write_text((WAREHOUSE / "nodes.yaml").read_text())
    code, _, err = run(
        capsys,
        "plan",
        str(tmp_path),
        str(WAREHOUSE / "modules.yaml"),
        str(WAREHOUSE / "fleet.yaml"),
    )
    assert code == 2
    assert "metadata.name: defined twice" in err
    assert str(tmp_path / "a.yaml") in err and str(tmp_path / "b.yaml") in err
    # one file named twice (directly and through its folder) is read once
    code, _, _ = run(
        capsys, "plan", str(WAREHOUSE), str(WAREHOUSE / "nodes.yaml"), "--generations", "3"
    )
    assert code == 0


def test_a_robot_trusts_its_own_computer_by_default() -> None:
    from fogfleet.api.v1alpha1.computenode import ComputeNodeSpec

    robot = {"tier": "robot", "hardwareType": "nuc"}
    assert ComputeNodeSpec.model_validate(robot).privacy == 3
    assert ComputeNodeSpec.model_validate({**robot, "privacyLevel": 1}).privacy == 1
    assert ComputeNodeSpec.model_validate({"tier": "cloud", "hardwareType": "vm"}).privacy == 0


def test_a_directory_of_fleets_is_planned_as_one_site(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two fleets on the same (small) edge nodes: the second plans into what the first left,
    and the order is printed."""
    docs = [d for f in ("nodes.yaml", "modules.yaml", "fleet.yaml") for d in _docs(WAREHOUSE / f)]
    capacity: dict[str, float] = {}
    for d in docs:
        if d["kind"] == "ComputeNode":
            if d["spec"]["tier"] == "edge":
                d["spec"]["capacity"]["cpu"] = "4"
            reserved = parse_cpu((d["spec"].get("reserved") or {}).get("cpu", 0))
            capacity[d["metadata"]["name"]] = parse_cpu(d["spec"]["capacity"]["cpu"]) - reserved
        if d["kind"] == "RobotFleet":
            d["spec"]["robots"] = ["robot-1", "robot-2"]
    second = []
    for d in docs:
        if d["kind"] in ("SoftwareModule", "RobotFleet"):
            copy = json.loads(json.dumps(d))
            copy["metadata"]["namespace"] = "other"
            if d["kind"] == "RobotFleet":
                copy["spec"]["robots"] = ["robot-3", "robot-4"]
            second.append(copy)
    (tmp_path / "site.yaml").write_text(yaml.safe_dump_all(docs + second))
    code, out, err = run(capsys, "plan", str(tmp_path), "--json", "--generations", "15")
    assert code == 0, err
    assert "in this order: warehouse/warehouse, other/warehouse" in err
    used: dict[str, float] = {}
    for plan in json.loads(out):
        for row in plan["placement"]:
            used[row["node"]] = used.get(row["node"], 0.0) + row["cpu"]
    assert all(cpu <= capacity[node] + 1e-9 for node, cpu in used.items()), used


def _docs(path: Path) -> list[dict]:
    return [d for d in yaml.safe_load_all(path.read_text()) if isinstance(d, dict)]


def test_a_plan_that_converged_early_does_not_say_the_time_budget_was_reached(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 35: fewer generations than asked is not a cut budget: a converged plan stops
    early too. The flag tells what the solver says stopped it."""
    import dataclasses

    from fogfleet.scheduling import solver

    real = solver.plan

    def converged(*args, **kwargs):  # type: ignore[no-untyped-def]
        schedule = real(*args, **kwargs)
        return dataclasses.replace(schedule, generations=3, time_budget_reached=False)

    monkeypatch.setattr(solver, "plan", converged)
    code, out, _ = run(
        capsys, "plan", str(SOLO), str(WAREHOUSE / "modules.yaml"), "--json", "--generations", "50"
    )
    assert code == 0 and json.loads(out)["timeBudgetReached"] is False


def _robot_too_small_to_hold_everything(tmp_path: Path) -> Path:
    """The single-robot fleet on a robot with 3Gi of memory to give: everything on board
    does not fit (the on-board reference is infeasible), offloading does."""
    nodes = (SOLO / "nodes.yaml").read_text()
    small = nodes.replace("capacity: {cpu: 8, memory: 16Gi}", "capacity: {cpu: 8, memory: 5Gi}")
    assert small != nodes
    (tmp_path / "nodes.yaml").write_text(small)
    (tmp_path / "fleet.yaml").write_text((SOLO / "fleet.yaml").read_text())
    (tmp_path / "modules.yaml").write_text((SOLO / "modules.yaml").read_text())
    return tmp_path


def test_an_infeasible_reference_is_reported_not_an_error(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Issue 35: with --scheduler all, the on-board reference not fitting the robot is a
    result of the comparison (said on stderr), not an exit 2: the planner's plan fits."""
    site = _robot_too_small_to_hold_everything(tmp_path)
    args = ("simulate", str(site), "--scheduler", "all", "--duration", "2", "--generations", "5")
    code, out, err = run(capsys, *args)
    assert code == 0, err
    assert "INFEASIBLE onboard (a reference, compared only): no placement fits" in err
    assert "INFEASIBLE nsga2" not in err and "OVERALL" in out
    # asked for on its own, the same plan is the run's result: exit 2
    code, _, err = run(capsys, "simulate", str(site), "--scheduler", "onboard", "--duration", "2")
    assert code == 2 and "INFEASIBLE onboard: no placement fits" in err


def test_overall_is_not_a_figure_beside_an_unplaced_module(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Issue 35: the fleet's rate covers the modules that ran; beside an unplaced module the
    OVERALL row says n/a and how many are unplaced, not 0.00%."""
    solo = (str(SOLO),)
    _, out, _ = run(capsys, "plan", *solo, "--scheduler", "onboard", "--json")
    doc = json.loads(out)
    doc["placement"] = [r for r in doc["placement"] if r["module"] != "nav-periphery"]
    saved = tmp_path / "plan.json"
    saved.write_text(json.dumps(doc))
    args = ("simulate", *solo, "--scheduler", "onboard", "--duration", "2")
    _, out, _ = run(capsys, *args, "--placement", str(saved))
    overall = next(line for line in out.splitlines() if line.startswith("OVERALL")).split()
    assert overall[1:4] == ["n/a", "(1", "unplaced)"]  # recorded
    assert overall[4].endswith("%")  # onboard, every module placed


def test_render_of_a_degraded_fleet_warns_on_stderr(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Issue 35: the YAML goes to stdout (often a pipe into kubectl); that the plan runs
    modules below their deadline's CPU is one line on stderr."""
    site = _short_site(tmp_path, allow_degraded=True)
    code, out, err = run(capsys, "render", str(site), "--generations", "5")
    assert code == 0 and "kind: Deployment" in out
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("DEGRADED single-robot/single-robot: degraded: the nodes are short")


def test_plan_and_simulate_name_the_same_worst_module(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 36: one definition of the worst module (domain.miss_rates) for the same plan;
    the warehouse's short simulation sees no miss, so the prediction names it in both."""
    from fogfleet.commandline.cli.planning import _print_plan

    args = ("--seed", "1", "--population", "16", "--generations", "3")
    code, out, _ = run(capsys, "plan", str(WAREHOUSE), "--json", *args)
    assert code == 0
    planned = json.loads(out)
    rates = planned["moduleMissRates"]
    assert planned["worstModule"] == max(sorted(rates), key=lambda m: rates[m])
    _print_plan(planned)
    assert f"(worst: {planned['worstModule']})" in capsys.readouterr().out
    code, out, _ = run(capsys, "simulate", str(WAREHOUSE), "--duration", "2", *args)
    assert code == 0
    worst = next(line for line in out.splitlines() if line.startswith("WORST MODULE"))
    assert worst.split()[2] == planned["worstModule"]
