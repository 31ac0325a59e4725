"""Runs of the paper's fleet on the ``paper`` bed's real nodes, measured and simulated.

    make bench-real        # = python -m e2e.bench.real (starts the paper bed when none runs)

Each run of the schedule (``protocol.Protocol``):

1. a fresh namespace gets the fleet's SoftwareModules and its RobotFleet with
   ``spec.scheduler`` set to the run's arm and seed; the operator (``fogfleet run``, scoped to
   the bench's namespaces, reading the bed's Prometheus) plans it (``nsga2``, ``onboard``) or
   hands it to kube-scheduler (``k8s-default``: plain Deployments, the real bindings read back
   from the fleet's status; ``k8s-requests``: the same with the modules' honest requests,
   ``scenario.honest_requests``, computed once before the first run);
2. once the fleet is Ready (kube-scheduler's arms: every instance Ready or Pending, which
   misses every cycle: ``protocol``'s Pending rule) and every running instance has reported
   cycles to Prometheus, and the previous run's namespace is gone, a warm-up in which the
   closed loop may correct what the plan got wrong (``DRIFT``, off for ``nsga2-static``), then,
   once the fleet is Ready again and rolled out, two snapshots of the workload's counters a
   window apart (``measure``); a plan that changes inside the window fails the run;
3. the simulator runs the placement the cluster ran, with the allocation it ran with, for the
   window, seeded with the run's seed (``fogfleet.sim.simulate``);
4. the namespace is deleted (and waited out while the next run starts).

Every run, failed or not, lands in ``bench-real.json`` (written after each run);
``report`` turns it into the tables, the statistics and the plot.
"""

from __future__ import annotations

import argparse
import json
import secrets
import shlex
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from e2e.bed import harness
from e2e.bed.cpu_meter import CpuMeter
from e2e.bed.kube import Kube, guard_kubeconfig
from e2e.bed.operator_fixtures import Operator, fleet, install_crds, wait_ready
from e2e.bench.real import report
from e2e.bench.real.binding import Key, wait_bound_or_pending
from e2e.bench.real.measure import (
    WindowRates,
    counting_unrun,
    simulated_rates,
    snapshot,
    window_rates,
)
from e2e.bench.real.protocol import (
    DEFAULT_RUNS,
    PENDING,
    PRIMARY,
    REQUESTS,
    Protocol,
    ScheduledRun,
    parse_arms,
)
from e2e.bench.real.record import RunResult, document, protocol_json
from e2e.bench.real.resume import part, runs_left
from e2e.bench.real.scenario import FLEET, PROFILE, ROOT, Scenario, honest_requests
from fogfleet.controllers.measure.observed import describe
from fogfleet.domain.rows import Learnt
from fogfleet.sim import simulate

__all__ = ["RunResult", "connect", "main", "run_bench"]

BENCH_LABEL = "fogfleet.io/bench"
# the closed loop (issue 10) as a run of a few minutes needs it: measured over 30 s, drift for
# 10 s, one correction per run (the next could come only after the window has ended)
DRIFT = {
    "windowSeconds": 30,
    "forSeconds": 10,
    "minIntervalSeconds": 900,
    "marginPercent": 5,
    "priorCycles": 100,
}
NO_DRIFT = {"enabled": False}
OBSERVE_INTERVAL_S = 5


def log(msg: str) -> None:
    print(f"[bench-real {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _wait_counted(kube: Kube, cluster: harness.Cluster, ns: str, instances: int) -> None:
    """Until Prometheus has cycles of every instance (the scrape and the first cycles)."""

    def counted() -> bool:
        cycles = snapshot(cluster.prometheus_query, ns).cycles
        return sum(1 for v in cycles.values() if v > 0) >= instances

    kube.wait_for(f"cycles of all {instances} instances in Prometheus", counted, 180, interval=2)


class PlanChanged(AssertionError):
    """The fleet's pods changed inside the window (their counters restarted)."""


def _apply_and_warm_up(
    kube: Kube,
    cluster: harness.Cluster,
    scenario: Scenario,
    run: ScheduledRun,
    namespace: str,
    protocol: Protocol,
    previous: str | None,
) -> tuple[float, set[Key]]:
    """Apply the run's fleet, wait until it runs and is counted, warm up; the seconds from
    apply to Ready (kube-scheduler's arms: to every instance Ready or Unschedulable) and the
    instances left Pending (the protocol's Pending rule)."""
    kube.apply(
        {
            "apiVersion": "v1",
            "kind": "Namespace",
            "metadata": {"name": namespace, "labels": {BENCH_LABEL: "true"}},
        }
    )
    t0 = time.monotonic()
    drift = DRIFT if run.closed_loop else NO_DRIFT
    kube.apply(scenario.namespaced(namespace, run.algorithm, drift, seed=run.seed))
    pending = _wait_running(kube, scenario, run, namespace)
    ready_s = time.monotonic() - t0
    _wait_counted(kube, cluster, namespace, scenario.instances - len(pending))
    if previous:
        _wait_gone(kube, previous)
    time.sleep(protocol.warmup_s)
    # a correction in the warm-up rolls pods out: measure the plan that stands
    if _wait_running(kube, scenario, run, namespace) != pending:
        raise PlanChanged("the instances left Pending changed in the warm-up")
    _wait_settled(kube, namespace)
    _wait_counted(kube, cluster, namespace, scenario.instances - len(pending))
    return ready_s, pending


def _wait_running(kube: Kube, scenario: Scenario, run: ScheduledRun, namespace: str) -> set[Key]:
    """The fleet Ready; in kube-scheduler's arms, every instance Ready or Unschedulable (the
    fleet is not Ready while one is Pending). The instances left Pending."""
    if run.kube_scheduler:
        return wait_bound_or_pending(kube, namespace, scenario.instances, timeout=300)
    wait_ready(kube, namespace, FLEET, timeout=300)
    return set()


def _measure_window(
    kube: Kube, cluster: harness.Cluster, running: int, namespace: str, window_s: float
) -> tuple[WindowRates, dict[str, Any], dict[str, float]]:
    """Two counter snapshots ``window_s`` apart: the rates, the fleet object at the end, and
    the CPU seconds each part of the bed spent in between."""
    planned = _plan_of(fleet(kube, namespace, FLEET))
    meter = CpuMeter()
    meter.start()
    before = snapshot(cluster.prometheus_query, namespace)
    time.sleep(window_s)
    after = snapshot(cluster.prometheus_query, namespace)
    cpu = meter.stop()
    missing = set(after.cycles) - set(before.cycles)
    if len(before.cycles) < running or missing:
        raise PlanChanged(
            f"instances came and went during the window (before {sorted(before.cycles)}, "
            f"after {sorted(after.cycles)})"
        )
    obj = fleet(kube, namespace, FLEET)
    if _plan_of(obj) != planned:
        raise PlanChanged("re-planned inside the window (the plan changed)")
    return window_rates(before, after), obj, cpu


def one_run(
    kube: Kube,
    cluster: harness.Cluster,
    scenario: Scenario,
    run: ScheduledRun,
    namespace: str,
    protocol: Protocol,
    previous: str | None = None,
) -> RunResult:
    """One run in ``namespace``; the ``previous`` run's namespace is deleted while this one
    starts, and gone (its pods too) before the warm-up begins. A run that does not complete
    comes back with ``failed`` set."""
    log(f"#{run.position + 1} block {run.block + 1}: {run.arm} seed {run.seed} in {namespace}")
    result = RunResult(run, protocol.window_s)
    try:
        result.ready_s, pending = _apply_and_warm_up(
            kube, cluster, scenario, run, namespace, protocol, previous
        )
        measured, obj, result.cpu_seconds = _measure_window(
            kube, cluster, scenario.instances - len(pending), namespace, protocol.window_s
        )
        # an instance left Pending missed every cycle it was due, measured and simulated
        due = scenario.due_cycles(pending, protocol.window_s)
        result.measured = counting_unrun(measured, due)
        result.corrected = tuple(_corrections(kube, namespace))
        result.placement = {
            p["robot"] + "/" + p["module"]: p["node"] for p in obj["status"]["placement"]
        } | {f"{robot}/{module}": PENDING for module, robot in pending}
        result.cpu = {
            p["robot"] + "/" + p["module"]: p["cpu"]
            for p in obj["status"]["placement"]
            if p.get("cpu")
        }
        placement, allocation = scenario.placement_of(obj)  # a Pending instance: not run
        sim = simulate(
            scenario.problem, placement, allocation, protocol.window_s, seed=run.seed,
            all_active=True,
        )  # fmt: skip
        simulated = counting_unrun(simulated_rates(sim.module_miss_rate, sim.module_cycles), due)
        result.simulated = simulated.modules
        result.simulated_cycles = simulated.cycles
    except (AssertionError, harness.HarnessError, OSError) as exc:  # a wait timed out, a
        # Prometheus query failed, PlanChanged: recorded, never dropped
        result.failed = str(exc).splitlines()[0][:300]
        log(f"  {run.arm} FAILED (recorded; the next run goes on): {result.failed}")
    finally:
        kube.kubectl("delete", "namespace", namespace, "--wait=false", check=False)
    if result.failed is None:
        doc = result.as_json()
        log(
            f"  {run.arm}: perception measured {_pct(doc['measured'][PRIMARY]['missRate'])}, "
            f"simulated {_pct(doc['simulated'][PRIMARY]['missRate'])}; all modules "
            f"{_pct(doc['measured']['allModules'])} (ready after {result.ready_s:.0f} s)"
            + (f"; learnt {'; '.join(result.corrected)}" if result.corrected else "")
        )
    return result


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x:.2%}"


def _plan_of(obj: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    return sorted(
        (p["robot"], p["module"], p["node"], str(p.get("cpu", "")))
        for p in (obj.get("status") or {}).get("placement") or []
    )


def _wait_settled(kube: Kube, namespace: str) -> None:
    """Until every Deployment of the run has rolled out (no old pod left running)."""

    def settled() -> bool:
        got = kube.kubectl("get", "deployments", "-n", namespace, "-o", "json", check=False)
        if got.returncode != 0:
            return False
        for d in json.loads(got.stdout)["items"]:
            st, want = d.get("status") or {}, (d.get("spec") or {}).get("replicas", 1)
            if st.get("observedGeneration") != d["metadata"].get("generation"):
                return False
            if st.get("updatedReplicas", 0) != want or st.get("replicas", 0) != want:
                return False
        return True

    kube.wait_for(f"deployments of {namespace} rolled out", settled, 300, interval=2)


def _corrections(kube: Kube, namespace: str) -> list[str]:
    """The profile corrections the operator adopted in the run (module, factor, noise)."""
    got = kube.kubectl("get", "softwaremodules", "-n", namespace, "-o", "json", check=False)
    if got.returncode != 0:
        return []
    out = []
    for m in json.loads(got.stdout)["items"]:
        for c in (m.get("status") or {}).get("profileCorrection") or []:
            learnt = Learnt(float(c["factor"]), float(c.get("noiseMillis", 0.0)) / 1e3)
            said = describe(c["hardwareType"], learnt, float(c.get("samples", 0.0)))
            out.append(f"{m['metadata']['name']} on {said}")
    return sorted(out)


def _wait_gone(kube: Kube, namespace: str) -> None:
    """Until a deleted run namespace (and so every pod of it) is gone."""

    def gone() -> bool:
        return kube.kubectl("get", "namespace", namespace, check=False).returncode != 0

    kube.wait_for(f"namespace {namespace} gone", gone, 180, interval=1)


def connect(profile: str = PROFILE) -> tuple[Kube, harness.Cluster]:
    """The bed of ``profile`` (the paper's by default): the running one, or started (a bed of
    another profile restarts)."""
    cluster = harness.ensure_up(profile=profile)
    server = guard_kubeconfig(cluster.kubeconfig, expected_server=cluster.api_server)
    kube = Kube(
        kubeconfig=cluster.kubeconfig,
        server=server,
        kubectl_bin=str(harness.BIN_DIR / "kubectl"),
        external=False,
        cluster=cluster,
    )
    return kube, cluster


class _ComputeNodes:
    """Apply the scenario's ComputeNodes for the benchmark; delete them afterwards."""

    def __init__(self, kube: Kube, scenario: Scenario) -> None:
        self.kube = kube
        self.ours = scenario.nodes()

    def __enter__(self) -> None:
        self.kube.apply(self.ours)

    def __exit__(self, *_: object) -> None:
        names = [n["metadata"]["name"] for n in self.ours]
        self.kube.kubectl("delete", "computenode", *names, "--ignore-not-found", check=False)


def run_bench(
    kube: Kube,
    cluster: harness.Cluster,
    protocol: Protocol,
    workdir: Path,
    on_run: Callable[[list[RunResult]], object] | None = None,
    runs: Sequence[ScheduledRun] | None = None,
) -> list[RunResult]:
    """Every run of the schedule (or ``runs``, the part of it a resumed run has left) on a
    running paper bed (the operator is started and stopped here); ``on_run`` sees the results
    after every run."""
    scenario = Scenario()
    missing = {n["metadata"]["name"] for n in scenario.nodes()} - set(cluster.real_nodes)
    if missing:
        raise SystemExit(f"the paper fleet needs the paper bed's nodes; missing {sorted(missing)}")
    install_crds(kube)
    # k8s-requests' requests, fixed here before its first run (from the profile rows only)
    by_arm = {REQUESTS: scenario.with_honest_requests()} if protocol.runs.get(REQUESTS) else {}
    if by_arm:
        got = honest_requests(scenario.of_kind("SoftwareModule")).values()
        log(f"{REQUESTS} requests: {'; '.join(r.describe() for r in got)}")
    tag = secrets.token_hex(2)
    todo = protocol.schedule() if runs is None else runs
    schedule = [(r, f"paper-{r.arm.replace('-', '')}-{r.seed}-{tag}") for r in todo]
    op = Operator(
        kube.kubeconfig,
        [ns for _, ns in schedule],
        workdir / "operator.log",
        {
            "FOGFLEET_PROMETHEUS_URL": cluster.prometheus_url,
            "FOGFLEET_OBSERVE_INTERVAL_SECONDS": str(OBSERVE_INTERVAL_S),
        },
    )
    results: list[RunResult] = []
    with _ComputeNodes(kube, scenario):
        op.start().wait_live()
        previous = None
        try:
            for run, ns in schedule:
                arm_scenario = by_arm.get(run.arm, scenario)
                results.append(one_run(kube, cluster, arm_scenario, run, ns, protocol, previous))
                previous = ns
                if on_run is not None:
                    on_run(results)
            if previous:
                _wait_gone(kube, previous)
        finally:
            op.stop()
    return results


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.real", description=__doc__)
    defaults = Protocol()
    ap.add_argument("--window", type=float, default=defaults.window_s, help="seconds measured")
    ap.add_argument("--warmup", type=float, default=defaults.warmup_s, help="seconds before it")
    ap.add_argument(
        "--arms",
        default=",".join(f"{a}={n}" for a, n in DEFAULT_RUNS.items()),
        help="runs per arm (the protocol's by default)",
    )
    ap.add_argument("--json", type=Path, default=ROOT / "bench-real.json", help="output file")
    ap.add_argument(
        "--resume",
        type=Path,
        help="a stopped run's bench-real.json: run the scheduled runs it never started, keep "
        "its runs, and write the whole to --json (refused if its protocol differs)",
    )
    ns = ap.parse_args(argv)
    try:
        runs = parse_arms(ns.arms)
    except ValueError as exc:
        ap.error(str(exc))
    if ns.window <= 0 or ns.warmup < 0:
        ap.error("--window must be > 0 and --warmup >= 0")
    protocol = Protocol(ns.window, ns.warmup, runs)
    command = "python -m e2e.bench.real " + shlex.join(sys.argv[1:] if argv is None else argv)
    scenario = Scenario()
    stopped: dict[str, Any] = {}
    todo = protocol.schedule()
    if ns.resume is not None:
        try:
            stopped = json.loads(ns.resume.read_text(encoding="utf-8"))
            todo = runs_left(stopped, protocol_json(protocol, scenario), todo)
        except (OSError, ValueError) as exc:
            ap.error(f"--resume {ns.resume}: {exc}")
    earlier = list(stopped.get("runs") or [])
    kube, cluster = connect()
    t0 = time.monotonic()

    def write(results: list[RunResult], complete: bool = False) -> dict[str, Any]:
        """bench-real.json after every run: a run that fails keeps what was measured."""
        doc = document(results, protocol, scenario, command.strip(), earlier)
        doc |= {"complete": complete, "totalSeconds": round(time.monotonic() - t0)}
        if earlier:
            ran = len(earlier) + len(results)
            before = stopped.get("parts") or [part(stopped, 1, len(earlier))]
            doc["parts"] = [*before, part(doc, len(earlier) + 1, ran)]
        ns.json.write_text(json.dumps(doc, indent=2) + "\n")
        return doc

    workdir = Path(tempfile.mkdtemp(prefix="bench-real-"))
    log(f"operator log: {workdir / 'operator.log'}; {len(todo)} runs")
    results = run_bench(kube, cluster, protocol, workdir, write, todo)
    doc = write(results, complete=True)
    print(report.table(doc))
    failed = [r for r in results if r.failed]
    print(
        f"\n{len(results)} runs ({len(failed)} failed) in {doc['totalSeconds']} s; wrote {ns.json}"
    )
    return 0
