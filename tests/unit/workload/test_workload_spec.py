"""The workload's pure parts: what the operator tells it, the CPU model, the message header."""

from __future__ import annotations

import json
import random

import pytest

from fogfleet.contract.dnn import PROFILE_KEY
from fogfleet.sim import episodes
from fogfleet.workload.messages import Header, decode, encode
from fogfleet.workload.spec import ExecRow, WorkloadSpec, exec_time, mean_episode_s

SPEC = {
    "cycleTimeMillis": "33",
    "activationPercent": 70,
    "topics": {
        "subscribes": [{"name": "scan", "sizeBytes": "8Ki", "rateHz": 10}],
        "publishes": [{"name": "cmd_vel", "sizeBytes": 64, "rateHz": "30"}],
    },
    "profile": [
        {"hardwareType": "bed-robot", "cpu": "500m", "meanMillis": 20, "stdMillis": 2},
        {"hardwareType": "bed-robot", "cpu": 0.25, "meanMillis": 38, "stdMillis": "4"},
    ],
}


def _env(**extra: str) -> dict[str, str]:
    return {
        "FOGFLEET_MODULE_SPEC": json.dumps(SPEC),
        "FOGFLEET_ROBOT": "bed-robot-1",
        "FOGFLEET_MODULE": "nav-controller",
        "FOGFLEET_CPU": "250m",
        **extra,
    }


def test_the_operators_environment_becomes_a_spec() -> None:
    spec = WorkloadSpec.from_env(_env())
    assert (spec.robot, spec.module, spec.cpu) == ("bed-robot-1", "nav-controller", 0.25)
    assert spec.cycle_s == pytest.approx(0.033) and spec.activation == pytest.approx(0.7)
    assert spec.subscribes[0].size_bytes == 8192 and spec.publishes[0].rate_hz == 30
    # the row for the CPU it was given: 38 ms with 0.25 cores
    assert spec.row == ExecRow(0.25, 0.038, 0.004)


def test_a_variants_standby_counts_the_remotes_silence_in_the_remotes_cycles() -> None:
    assert WorkloadSpec.from_env(_env()).takeover_cycle_s == pytest.approx(0.033)
    variant = {**SPEC, "cycleTimeMillis": 200, "fallback": {"remoteCycleTimeMillis": 33}}
    spec = WorkloadSpec.from_env(_env(FOGFLEET_MODULE_SPEC=json.dumps(variant)))
    assert spec.cycle_s == pytest.approx(0.2) and spec.takeover_cycle_s == pytest.approx(0.033)


def test_a_missing_or_broken_spec_names_the_variable() -> None:
    with pytest.raises(ValueError, match="FOGFLEET_MODULE_SPEC is not set"):
        WorkloadSpec.from_env({})
    with pytest.raises(ValueError, match="FOGFLEET_MODULE_SPEC: not JSON"):
        WorkloadSpec.from_env({"FOGFLEET_MODULE_SPEC": "{"})
    with pytest.raises(ValueError, match="cycleTimeMillis"):
        WorkloadSpec.from_env({"FOGFLEET_MODULE_SPEC": json.dumps({"profile": []})})


def test_the_profile_row_is_the_largest_cpu_within_the_limit() -> None:
    rows = [ExecRow(0.25, 0.04, 0.0), ExecRow(0.5, 0.02, 0.0), ExecRow(2.0, 0.008, 0.0)]
    assert exec_time(rows, 1.0).cpu == 0.5
    assert exec_time(rows, 2.0).cpu == 2.0
    assert exec_time(rows, 0.1).cpu == 0.25  # below every row: the smallest
    with pytest.raises(ValueError, match="no execution-time profile"):
        exec_time([], 1.0)


def test_the_header_round_trips_and_pads_to_the_topic_size() -> None:
    h = Header("bed-robot-2", "lidar", 7, 1_700_000_000_000_000_000, 42)
    data = encode(h, 1024)
    assert len(data) == 1024 and decode(data) == h
    assert decode("garbage") is None


@pytest.mark.parametrize("activation", [0.08, 0.14, 0.3, 0.7, 0.99])
def test_activation_episodes_are_the_simulators(activation: float) -> None:
    assert mean_episode_s(activation) == pytest.approx(episodes.mean_episode_s(activation))


def test_sampled_work_is_never_negative() -> None:
    from fogfleet.workload.spec import sample_exec_seconds

    rng = random.Random(1)
    row = ExecRow(1.0, 0.01, 0.05)  # a spread larger than the mean
    assert min(sample_exec_seconds(row, rng) for _ in range(1000)) >= 0.001


@pytest.mark.integration
def test_the_workload_imports_with_only_what_its_image_installs() -> None:
    """The ROS 2 image installs fogfleet with --no-deps (rclpy and prometheus-client only):
    no workload entry point may pull pydantic, numpy, kopf or kubernetes in, nor any fogfleet
    package but the workload and the stdlib-only contract."""
    import subprocess
    import sys

    blocked = ["pydantic", "pydantic_settings", "numpy", "scipy", "kopf", "kubernetes", "pymoo",
               "yaml", "prometheus_api_client", "requests", "highspy", "tqdm"]  # fmt: skip
    code = (
        "import sys\n"
        + "".join(f"sys.modules[{name!r}] = None\n" for name in blocked)
        + "import fogfleet.workload.__main__, fogfleet.workload.module, fogfleet.workload.probe\n"
        + "import fogfleet.workload.discovery, fogfleet.workload.profile\n"
        + "print(' '.join(sorted(m for m in sys.modules if m.startswith('fogfleet.'))))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    loaded = proc.stdout.split()
    assert any(m.startswith("fogfleet.contract") for m in loaded)
    assert all(m.startswith(("fogfleet.workload", "fogfleet.contract")) for m in loaded), loaded


def test_a_plain_deployment_without_a_limit_plays_its_nodes_rows_at_full_parallelism() -> None:
    """The k8s-default baseline: no FOGFLEET_CPU, the node from the downward API, the rows of
    whichever node kube-scheduler chose, the largest parallelism (the simulator's nominal)."""
    body = {
        "cycleTimeMillis": 100,
        "profile": [{"hardwareType": "default", "cpu": 1, "meanMillis": 50}],
        "profileByNode": {
            "robot-1": [{"hardwareType": "nuc", "cpu": "250m", "meanMillis": 80},
                        {"hardwareType": "nuc", "cpu": "500m", "meanMillis": 45}],
            "edge-1": [{"hardwareType": "xeon", "cpu": 2, "meanMillis": 20, "stdMillis": 2}],
        },
    }  # fmt: skip
    env = {"FOGFLEET_MODULE_SPEC": json.dumps(body), "FOGFLEET_CPU": ""}
    on_robot = WorkloadSpec.from_env({**env, "FOGFLEET_NODE": "robot-1"})
    assert on_robot.cpu is None and on_robot.row == ExecRow(0.5, 0.045, 0.0)
    on_edge = WorkloadSpec.from_env({**env, "FOGFLEET_NODE": "edge-1"})
    assert on_edge.row == ExecRow(2.0, 0.02, 0.002)
    # a node the spec does not know (or no node): the module's own rows
    assert WorkloadSpec.from_env(env).row == ExecRow(1.0, 0.05, 0.0)


def test_a_split_modules_profiling_job_names_the_split_points_to_time() -> None:
    """contract.dnn: PROFILE_KEY instead of SPEC_KEY, beside what every module spec has."""
    body = {"cycleTimeMillis": 100, PROFILE_KEY: {"splitPoints": ["b6", "bneck"]}}
    spec = WorkloadSpec.from_env({"FOGFLEET_MODULE_SPEC": json.dumps(body)})
    assert spec.dnn_profile == ("b6", "bneck") and spec.dnn is None
    assert spec.cycle_s == pytest.approx(0.1)
    assert WorkloadSpec.from_env(_env()).dnn_profile is None
    for bad in ({}, {"splitPoints": "b6"}, {"splitPoints": ["b6", ""]}, {"splitPoints": [6]}):
        text = json.dumps({**body, PROFILE_KEY: bad})
        with pytest.raises(ValueError, match=r"dnnProfile\.splitPoints"):
            WorkloadSpec.from_env({"FOGFLEET_MODULE_SPEC": text})
