"""``make bench-scale``: the operator at fleet scale on the local control plane (kwok nodes).

    .venv/bin/python -m e2e.bench.scale [--sizes 100,300,1000] [--out bench-scale.json]
                                        [--operator-only] [--repeats 1]

For each size n: n robots x 8 modules (the warehouse modules) on ceil(0.4 n) edge nodes - the
stand-in benchmark's fleet shape (``synthetic_fleet``: 12 edge cores per robot on average) -
every Node a kwok node, every ComputeNode a real object validated by the real API server:

1. **plain**: the same pods as plain Deployments (``render_fleet(..., baseline=True)``) and
   the robots' discovery servers (``e2e.bench.cluster.plain_discovery``: the operator's fleet runs
   them too), one ``kubectl apply --server-side``, kube-scheduler alone: seconds from apply to
   all module pods Running
   (and ``plainApplySeconds``: when kubectl returned, having written every Deployment).
2. **operator**: a fresh ``fogfleet run`` (so its peak RSS is this size's) serves a fresh
   namespace; the RobotFleet is applied: seconds to all Running, ``status.planningMillis``
   (the first plan), and the **Ready lag**: when a poll of the fleet (every 0.2 s, started
   before the apply) first saw ``Ready=True`` for all modules, minus when the pod watch saw the
   last pod Running.
3. **one robot joins**: a new kwok Node and ComputeNode, then the fleet's ``spec.robots`` gains
   it: the re-plan's ``status.planningMillis``, the wall seconds from the patch until the fleet
   is Ready with the robot's modules placed, and ``status.migrations`` (instances moved). The
   first joins as soon as the fleet is Ready, while kube-controller-manager still works
   through the rollout's Deployment statuses on the same cores; a second (``settled*``) once
   the control plane has used less than half a core for 10 s (``settleWaitSeconds``: how
   long that took), as in a fleet that has been running a while.
4. **CPU by part of the bed** (``plainCpuSeconds``, ``operatorCpuSeconds``): what etcd, the
   API server, kube-controller-manager, kube-scheduler, kwok, the operator and the benchmark
   itself used from apply to all Running, and the machine's busy seconds (``e2e/bed/cpu_meter.py``).
5. **API writes** (``apiWrites``, ``apiWritesPerSecond``): the operator's POST/PUT/PATCH/DELETE
   from apply to all Running, from client-go's ``rest_client_requests_total`` on its /metrics,
   and their rate over that time.
6. **operator RSS**: ``VmHWM`` (peak, planning included) and ``VmRSS`` (what it holds once the
   fleet is Ready again: caches, plans) of the operator process at the end of the size.

Prints one table and writes ``bench-scale.json`` at the repository root (git-ignored):
``{"sizes": [{"robots", "pods", "plainSeconds", "operatorSeconds", "planningSeconds",
"readyLagSeconds", "operatorPeakRssMiB", "firstPlanSeconds", "incrementalReplanSeconds",
"incrementalMoved", ...}], "rssSlopes": [{"fromPods", "toPods", "peakMiBPer1000Pods"}]}``
(the operator's peak RSS growth between consecutive sizes). With ``--repeats n`` each size
runs n times, plain and operator side by side in each, and its row holds the medians
(``runs``: every run). The cluster's client rate limits
are the harness's (raised for both paths, e2e/bed/cluster.py); the fake nodes heartbeat
as slowly as a large cluster's for the run (``cluster.heartbeats.relaxed``: 120 s Leases; the
bed's 10 s ones, renewed every 2.5 s, cost hundreds of writes a second at hundreds of nodes
and expired at 300 robots).
Everything talks to 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import itertools
import json
import math
import os
import secrets
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT, ROOT / "operator"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from e2e.bed import harness, heartbeats  # noqa: E402
from e2e.bed.cpu_meter import CONTROL_PLANE, CpuMeter  # noqa: E402
from e2e.bed.kube import Kube  # noqa: E402
from e2e.bed.operator_fixtures import Operator  # noqa: E402
from e2e.bench.cluster import (  # noqa: E402
    BENCH_LABEL,
    FleetSpec,
    Watcher,
    connect,
    create_namespace,
    delete_namespace,
    large_spec,
    leftover_namespaces,
    loadavg,
    log,
    run_plain,
    server_side_apply,
    setup_cluster,
    table,
    teardown_cluster,
)
from e2e.portable.metrics import read as read_metrics  # noqa: E402
from fogfleet.bench.record import machine  # noqa: E402

Obj = dict[str, Any]
EDGES_PER_ROBOT = 0.4
POLL_SECONDS = 0.2
# the second robot joins once the control plane is this quiet (cores over the window)
QUIET_CORES = 0.5
QUIET_WINDOW_SECONDS = 10.0
QUIET_MAX_SECONDS = 300.0
MANAGER = "fogfleet-bench-scale"


def edges_for(robots: int) -> int:
    return max(2, math.ceil(EDGES_PER_ROBOT * robots))


def timeout_for(pods: int) -> float:
    return 180.0 + 0.5 * pods


class FleetPoller:
    """Reads the RobotFleet every POLL_SECONDS from before the apply; records when Ready=True
    (with ``pods`` modules placed) was first seen."""

    def __init__(self, kube: Kube, ns: str, name: str, pods: int) -> None:
        from kubernetes import client

        self.api = kube.api_client()
        self.custom = client.CustomObjectsApi(self.api)
        self.ns, self.name, self.pods = ns, name, pods
        self.ready_at: float | None = None
        self.status: Obj = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from kubernetes.client.exceptions import ApiException

        while not self._stop.is_set():
            try:
                obj = self.custom.get_namespaced_custom_object(
                    "fogfleet.io", "v1alpha1", self.ns, "robotfleets", self.name
                )
            except ApiException:
                obj = {}
            status = obj.get("status") or {}
            self.status = status
            if self.ready_at is None and is_ready(status, self.pods):
                self.ready_at = time.monotonic()
            self._stop.wait(POLL_SECONDS)

    def wait_ready(self, timeout: float) -> float:
        deadline = time.monotonic() + timeout
        while self.ready_at is None:
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.ns}/{self.name} not Ready after {timeout:.0f}s")
            time.sleep(POLL_SECONDS)
        return self.ready_at

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.api.close()


def is_ready(status: Obj, pods: int) -> bool:
    conds = {c["type"]: c["status"] for c in status.get("conditions") or []}
    return conds.get("Ready") == "True" and status.get("modulesPlaced") == pods


def wall_clock(monotonic: float) -> str:
    """A time.monotonic() value as UTC wall-clock time with milliseconds (as the logs print)."""
    at = time.time() - (time.monotonic() - monotonic)
    return datetime.datetime.fromtimestamp(at, datetime.UTC).strftime("%H:%M:%S.%f")[:-3]


def rss_mib(pid: int, field: str = "VmHWM") -> float:
    """The process's peak (VmHWM) or current (VmRSS) resident memory."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def new_robot_name(spec: FleetSpec, k: int) -> str:
    return f"bench-robot-{len(spec.fleet['spec']['robots']) + k}"


def joining_robot(spec: FleetSpec, k: int = 1) -> tuple[Obj, Obj, str]:
    """The k-th new robot, like the fleet's first: (its kwok Node, its ComputeNode, its name)."""
    robots = spec.fleet["spec"]["robots"]
    name = new_robot_name(spec, k)
    template = next(c for c in spec.compute_nodes if c["metadata"]["name"] == robots[0])
    cn = copy.deepcopy(template)
    cn["metadata"] = {"name": name, "labels": {BENCH_LABEL: "true"}}
    cap = cn["spec"]["capacity"]
    node = harness.node_object(
        name,
        "robot",
        cn["spec"]["hardwareType"],
        int(cap["cpu"]),
        int(str(cap["memory"]).removesuffix("Gi")),
        robot=name,
    )
    node["metadata"]["labels"][BENCH_LABEL] = "true"
    return node, cn, name


def run_operator_size(
    kube: Kube, spec: FleetSpec, ns: str, logdir: Path, env: dict[str, str]
) -> Obj:
    op = Operator(kube.kubeconfig, [ns], logdir / f"operator-{ns}.log", env)
    timeout = timeout_for(spec.pods)
    create_namespace(kube, ns)
    server_side_apply(kube, spec.modules_in(ns), MANAGER)
    op.start().wait_live()
    assert op.proc is not None
    try:
        watcher = Watcher(kube, ns, spec.pods)
        poller = FleetPoller(kube, ns, spec.fleet_name, spec.pods)
        meter = CpuMeter({"fogfleet": op.proc.pid, "benchmark": os.getpid()})
        try:
            writes_before = api_writes(op.metrics_port)
            meter.start()
            t0 = time.monotonic()
            server_side_apply(kube, [spec.fleet_in(ns)], MANAGER, timeout=timeout)
            watcher.wait(timeout)
            meter.stop()
            writes = api_writes(op.metrics_port) - writes_before
            ready_at = poller.wait_ready(timeout)
        finally:
            watcher.close()
        assert watcher.all_running is not None
        first = dict(poller.status)
        row: Obj = {
            "operatorSeconds": watcher.all_running - t0,
            "planningSeconds": (first.get("planningMillis") or 0) / 1e3,
            "firstPlanSeconds": (first.get("planningMillis") or 0) / 1e3,
            "readyLagSeconds": ready_at - watcher.all_running,
            "lastDeploymentSeconds": (watcher.last_dep or math.nan) - t0,
            "operatorCpuSeconds": meter.seconds,
            "apiWrites": writes,
            "apiWritesPerSecond": writes / (watcher.all_running - t0),
        }
        log(
            f"{spec.key} operator: all Running {row['operatorSeconds']:.1f}s, planning "
            f"{row['planningSeconds']:.1f}s, Ready lag {row['readyLagSeconds']:.2f}s (last pod "
            f"Running at {wall_clock(watcher.all_running)}, Ready seen at "
            f"{wall_clock(ready_at)}: compare with the operator's log)"
        )
        row |= robot_joins(kube, spec, ns, poller, first, timeout, 1)
        row["settleWaitSeconds"] = wait_quiet()
        settled = robot_joins(kube, spec, ns, poller, dict(poller.status), timeout, 2)
        row |= {f"settled{k[0].upper()}{k[1:]}": v for k, v in settled.items()}
        poller.close()
        row["operatorPeakRssMiB"] = rss_mib(op.proc.pid)
        row["operatorRssAfterMiB"] = rss_mib(op.proc.pid, "VmRSS")
        return row
    finally:
        delete_namespace(kube, ns, timeout=timeout)
        op.stop()


WRITE_METHODS = ("POST", "PUT", "PATCH", "DELETE")


def api_writes(metrics_port: int) -> float:
    """The operator's API writes so far: client-go's ``rest_client_requests_total`` from its
    /metrics, summed over the write methods (kopf's own annotation patches and the Lease are
    not counted: they do not go through fogfleet's client)."""
    scraped = read_metrics(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10)
    return sum(scraped.total("rest_client_requests_total", method=m) for m in WRITE_METHODS)


def wait_quiet(window: float = QUIET_WINDOW_SECONDS) -> float:
    """Seconds until the control plane used less than ``QUIET_CORES`` over a ``window``
    (kube-controller-manager works through thousands of Deployments' statuses for minutes
    after their pods run), at most ``QUIET_MAX_SECONDS``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < QUIET_MAX_SECONDS:
        meter = CpuMeter()
        meter.start()
        time.sleep(window)
        used = sum(v for k, v in meter.stop().items() if k in CONTROL_PLANE) / window
        if used < QUIET_CORES:
            break
    waited = time.monotonic() - t0
    log(f"control plane below {QUIET_CORES} of a core after {waited:.0f}s")
    return waited


def robot_joins(
    kube: Kube,
    spec: FleetSpec,
    ns: str,
    poller: FleetPoller,
    before: Obj,
    timeout: float,
    k: int,
) -> Obj:
    """The k-th new robot joins the fleet (its Node and ComputeNode first); the fleet's re-plan
    and how long until it is Ready again."""
    node, cn, name = joining_robot(spec, k)
    kube.apply([node])
    server_side_apply(kube, [cn], MANAGER)
    kube.wait_for(
        f"Node {name} Ready",
        lambda: any(
            c["type"] == "Ready" and c["status"] == "True"
            for c in kube.kubectl_json("get", "node", name).get("status", {}).get("conditions", [])
        ),
        timeout=120,
    )
    pods = spec.pods + k * len(spec.fleet["spec"]["modules"])
    poller.pods, poller.ready_at = pods, None
    robots = [*spec.fleet["spec"]["robots"], *(new_robot_name(spec, n) for n in range(1, k + 1))]
    t0 = time.monotonic()
    kube.kubectl(
        "patch", "robotfleet", spec.fleet_name, "-n", ns, "--type=merge",
        "-p", json.dumps({"spec": {"robots": robots}}),
    )  # fmt: skip
    ready_at = poller.wait_ready(timeout)
    after = dict(poller.status)
    if after.get("lastPlanTime") == before.get("lastPlanTime"):
        raise RuntimeError("the fleet became Ready without a new plan")
    row = {
        "incrementalReplanSeconds": (after.get("planningMillis") or 0) / 1e3,
        "joinToReadySeconds": ready_at - t0,
        "incrementalMoved": int(after.get("migrations") or 0),
    }
    log(
        f"{spec.key} robot {k} joins: re-plan {row['incrementalReplanSeconds']:.1f}s, Ready after "
        f"{row['joinToReadySeconds']:.1f}s, {row['incrementalMoved']} moved"
    )
    return row


def bench_size(
    kube: Kube, robots: int, token: str, logdir: Path, env: dict[str, str], plain_too: bool = True
) -> Obj:
    spec = large_spec(robots, edges_for(robots))
    log(f"{spec.key}: {spec.pods} pods on {edges_for(robots)} edge nodes; load {loadavg()}")
    plain_ns = f"bench-{token}-scale-plain-{robots}"
    op_ns = f"bench-{token}-scale-op-{robots}"
    row: Obj = {"robots": robots, "pods": spec.pods, "edges": edges_for(robots)}
    try:
        setup_cluster(kube, [spec])
        if plain_too:
            meter = CpuMeter({"benchmark": os.getpid()})
            plain = run_plain(kube, spec, plain_ns, timeout_for(spec.pods), meter)
            row["plainSeconds"] = plain["total_s"]
            row["plainCpuSeconds"] = meter.seconds
            row["plainApplySeconds"] = plain["kubectl_s"]  # kubectl's own share of it
            row["plainDiscoveryServers"] = plain["discovery_servers"]
            log(
                f"{spec.key} plain: all Running {plain['total_s']:.1f}s (kubectl apply returned "
                f"after {plain['kubectl_s']:.1f}s)"
            )
            delete_namespace(kube, plain_ns, timeout=timeout_for(spec.pods))
        row |= run_operator_size(kube, spec, op_ns, logdir, env)
        if plain_too:
            # issue 46's target (<= 1.0 at 1000 robots); the operator's overhead beyond planning
            row["wholeRatio"] = row["operatorSeconds"] / row["plainSeconds"]
            row["ratio"] = (row["operatorSeconds"] - row["planningSeconds"]) / row["plainSeconds"]
    except Exception as exc:  # keep the other sizes; the row says what failed
        log(f"{spec.key}: FAILED: {exc!r}")
        row["error"] = repr(exc)
    finally:
        try:
            teardown_cluster(kube, [plain_ns, op_ns])
        except Exception as exc:  # keep what was measured; the next run removes leftovers
            log(f"{spec.key}: cleanup failed: {exc!r}")
    return row


def table_cells(rows: list[Obj]) -> tuple[list[str], list[list[str]]]:
    """The table's header and its cells, one line per size ("-" where a run measured nothing)."""

    def f(row: Obj, key: str, fmt: str = "{:.1f}") -> str:
        v = row.get(key)
        return fmt.format(v) if isinstance(v, int | float) and v == v else "-"

    header = [
        "robots", "pods", "plain s", "operator s", "operator/plain", "first plan s",
        "(op-plan)/plain", "Ready lag s", "join re-plan s", "join->Ready s", "moved",
        "settled re-plan s", "settled join->Ready s", "peak RSS MiB", "RSS after MiB",
        "API writes", "writes/s",
    ]  # fmt: skip
    columns = [
        ("plainSeconds", "{:.1f}"),
        ("operatorSeconds", "{:.1f}"),
        ("wholeRatio", "{:.2f}"),
        ("firstPlanSeconds", "{:.1f}"),
        ("ratio", "{:.2f}"),
        ("readyLagSeconds", "{:.2f}"),
        ("incrementalReplanSeconds", "{:.1f}"),
        ("joinToReadySeconds", "{:.1f}"),
        ("incrementalMoved", "{:d}"),
        ("settledIncrementalReplanSeconds", "{:.1f}"),
        ("settledJoinToReadySeconds", "{:.1f}"),
        ("operatorPeakRssMiB", "{:.0f}"),
        ("operatorRssAfterMiB", "{:.0f}"),
        ("apiWrites", "{:.0f}"),
        ("apiWritesPerSecond", "{:.1f}"),
    ]
    lines = [[str(r["robots"]), str(r["pods"]), *(f(r, k, fm) for k, fm in columns)] for r in rows]
    return header, lines


def format_rows(rows: list[Obj]) -> str:
    header, lines = table_cells(rows)
    errors = [f"{r['robots']} robots: {r['error']}" for r in rows if "error" in r]
    return "\n".join([table(lines, header), *errors])


def page_rows(rows: list[Obj]) -> list[dict[str, str]]:
    """The table as the benchmarks page renders a record's result (``fogfleet bench page``):
    one mapping per size, with the repeats each median is over."""
    header, lines = table_cells(rows)
    return [
        dict(zip(header, line, strict=True)) | {"runs": str(r.get("repeats", 1))}
        for r, line in zip(rows, lines, strict=True)
    ]


CPU_PARTS = ("machine", *CONTROL_PLANE, "fogfleet", "benchmark")


def format_cpu(rows: list[Obj]) -> str:
    """CPU seconds per part of the bed while each path rolled out (apply to all Running)."""
    header = ["robots", "path", "wall s", *CPU_PARTS]
    lines = []
    for r in rows:
        for path, wall_key, cpu_key in (
            ("plain", "plainSeconds", "plainCpuSeconds"),
            ("fogfleet", "operatorSeconds", "operatorCpuSeconds"),
        ):
            cpu = r.get(cpu_key)
            if not isinstance(cpu, dict):
                continue
            wall = r.get(wall_key)
            lines.append(
                [
                    str(r["robots"]),
                    path,
                    f"{wall:.1f}" if isinstance(wall, int | float) else "-",
                    *(f"{cpu[k]:.1f}" if k in cpu else "-" for k in CPU_PARTS),
                ]
            )
    return table(lines, header) if lines else ""


def median_row(runs: list[Obj]) -> Obj:
    """One size's row over repeated runs: each number the median over the runs that finished
    (the ratio: the median of each run's own, plain and operator side by side), CPU seconds
    per part likewise; ``runs`` keeps every run, ``error`` says which failed."""
    done = [r for r in runs if "error" not in r]
    if not done:
        return runs[0] | {"runs": runs, "repeats": len(runs)}
    row: Obj = dict(done[0])
    for key, value in done[0].items():
        if isinstance(value, int | float) and not isinstance(value, bool):
            values = [r[key] for r in done if isinstance(r.get(key), int | float)]
            row[key] = statistics.median(values)
            if isinstance(value, int):  # counts stay counts
                row[key] = round(row[key])
        elif isinstance(value, dict):
            row[key] = {
                k: round(statistics.median(r[key][k] for r in done if k in r.get(key, {})), 2)
                for k in value
            }
    row |= {"runs": runs, "repeats": len(runs)}
    failed = [r["error"] for r in runs if "error" in r]
    if failed:
        row["error"] = f"{len(failed)} of {len(runs)} runs failed: {failed[0]}"
    return row


def rss_slopes(rows: list[Obj]) -> list[Obj]:
    """Operator peak RSS growth between consecutive measured sizes, in MiB per 1000 pods: a
    footprint linear in the pods keeps it constant from one interval to the next."""
    got = sorted(
        (r for r in rows if isinstance(r.get("operatorPeakRssMiB"), int | float)),
        key=lambda r: r["pods"],
    )
    return [
        {
            "fromPods": a["pods"],
            "toPods": b["pods"],
            "peakMiBPer1000Pods": round(
                1000
                * (b["operatorPeakRssMiB"] - a["operatorPeakRssMiB"])
                / (b["pods"] - a["pods"]),
                1,
            ),
        }
        for a, b in itertools.pairwise(got)
        if b["pods"] > a["pods"]
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100,300,1000", help="robot counts, comma-separated")
    ap.add_argument("--out", default=str(ROOT / "bench-scale.json"))
    ap.add_argument("--operator-log-level", default="INFO", help="FOGFLEET_LOG_LEVEL")
    ap.add_argument(
        "--operator-only",
        action="store_true",
        help="skip the plain Deployments (no ratio): re-measure the operator's side alone",
    )
    ap.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="runs per size, plain and operator side by side in each; the table shows medians",
    )
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    # kwok nodes only: the default bed's kube-routers would sync the operator's NetworkPolicies
    # (which plain Deployments do not have) into iptables on the cores both sides share
    kube = connect(profile="kwok")
    stale = leftover_namespaces(kube)
    if stale:
        log(f"removing {len(stale)} namespaces left by an earlier benchmark")
        teardown_cluster(kube, stale, operator_running=False)
    token = secrets.token_hex(2)
    logdir = Path(tempfile.mkdtemp(prefix="fogfleet-bench-scale-"))
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    env = {"FOGFLEET_LOG_LEVEL": args.operator_log_level}
    with heartbeats.relaxed() as beats:
        rows = [
            median_row(
                [
                    bench_size(kube, n, f"{token}{k}", logdir, env, not args.operator_only)
                    for k in range(max(1, args.repeats))
                ]
            )
            for n in sizes
        ]
    words = argv if argv is not None else sys.argv[1:]
    report: Obj = {
        # a benchmark record (fogfleet.bench.record): the page's table, when, where, how
        "suite": "scale",
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine(),
        "command": " ".join(["python", "-m", "e2e.bench.scale", *words]),
        "result": page_rows(rows),
        "started": started,
        "edgesPerRobot": EDGES_PER_ROBOT,
        "nodeLeaseSeconds": beats.lease_seconds,
        "nodeMonitorGracePeriod": beats.grace_period,
        "sizes": rows,
        "rssSlopes": rss_slopes(rows),
        "operatorLogs": str(logdir),
    }
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n")
    print(f"fogfleet fleet-scale benchmark ({started}; load after: {loadavg()})")
    print(format_rows(rows))
    cpu = format_cpu(rows)
    if cpu:
        print("CPU seconds from apply to all Running, by part of the bed:")
        print(cpu)
    for sl in report["rssSlopes"]:
        print(
            f"operator peak RSS {sl['fromPods']} -> {sl['toPods']} pods: "
            f"{sl['peakMiBPer1000Pods']:.0f} MiB per 1000 pods"
        )
    print(f"written: {args.out}; operator logs: {logdir}")
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
