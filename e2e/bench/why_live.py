"""``make bench-why-live``: ``kubectl fogfleet why`` on a contended 1000-robot fleet on the
local bed, reading from the API included (issue 46's target: under 2 s).

Protocol (fixed before the first result):

- **Bed:** the local bed's ``kwok`` profile (the control plane and kwok nodes, no real node:
  started, or restarted from another profile); the fleet on its kwok nodes, which heartbeat as
  a large cluster's do for the run (``heartbeats.relaxed``: 120 s Leases, as ``make
  bench-scale`` has them). Revised before any result: on the default bed, its three real
  nodes' kube-routers synced the 1000 robots' NetworkPolicies into iptables at a load of 24
  and the rollout never finished (1 353 of 9 000 Deployments in 9 minutes).
- **Fleet:** ``cluster.large_spec(robots, edges)``, the synthetic warehouse robots; at 1000
  robots on 100 edges (0.1 edge per robot, where ``make bench-scale`` gives 0.4) the edges are
  short of CPU, so the explained moves land on contended nodes. The operator (a local process)
  plans it and every module pod runs before anything is timed.
- **Command:** ``kubectl fogfleet why FLEET scene-segmentation --robot <the middle robot>
  -o json``, as users run it: a new process with the bed's kubeconfig. It runs ``--runs``
  times, and each time beside the same command with ``--local`` (the plugin explains by
  itself from the API's objects instead of asking the operator: what it does when the
  operator cannot answer) and beside the same command of a ``--baseline`` checkout (its
  ``operator/`` directory first on PYTHONPATH, e.g. a ``git worktree`` of an earlier commit),
  in alternating order. Revised after the first results of 2026-11-30 and before any result
  of the operator's answer: the ``--local`` row was added when the plugin began to ask the
  operator; a run of this checkout that the operator did not answer fails the benchmark.
- **Endpoint:** the command's wall seconds, median over the runs.
- **Also:** in this process, the ``--local`` read and explanation split into the API reads
  (from the first ``Source`` call until the last ends: the plugin reads side by side; and each
  method's own seconds), the snapshot and problem build, and the explanation, median over the
  runs; the process's import seconds (``--help``), which every command pays; and the seconds
  the operator took to answer each request (its log), median.
"""

from __future__ import annotations

import argparse
import os
import re
import secrets
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from e2e.bed import heartbeats
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import ROOT, Operator
from e2e.bench.cluster import (
    Watcher,
    connect,
    create_namespace,
    large_spec,
    log,
    server_side_apply,
    setup_cluster,
    teardown_cluster,
)
from fogfleet.bench.record import write_record
from fogfleet.bench.scheduling import format_table

MODULE = "scene-segmentation"
ANSWERED = re.compile(r"ExplanationRequest \S+ answered in (\d+) ms")
Obj = dict[str, Any]
LOCAL = "this checkout, --local"


def _command(kube: Kube, ns: str, fleet: str, robot: str) -> list[str]:
    return [
        *("-m", "fogfleet.commandline.kubectl", "why", fleet, MODULE, "--robot", robot),
        *("--kubeconfig", str(kube.kubeconfig), "-n", ns, "-o", "json"),
    ]


def _wall(args: list[str], operator_dir: Path | None, answered: bool = False) -> float:
    """Seconds of ``python ARGS`` in a new process (``operator_dir`` first on its path);
    ``answered``: the operator must have answered (the plugin did not explain by itself)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if operator_dir is not None:
        env["PYTHONPATH"] = str(operator_dir)
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=300, cwd=ROOT, env=env
    )
    took = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:4])} failed: {out.stderr[-400:]}")
    if answered and "did not explain" in out.stderr:
        raise RuntimeError(f"the operator did not answer: {out.stderr[-400:]}")
    return took


def _answer_seconds(log_file: Path) -> list[float]:
    """The seconds the operator took per answered request (``runtime.explanations``' log)."""
    text = log_file.read_text(errors="replace") if log_file.exists() else ""
    return [float(ms) / 1e3 for ms in ANSWERED.findall(text)]


class TimedSource:
    """The plugin's ``Source`` with the seconds each method's calls took, and when the last
    call ended (the plugin reads side by side: the API reads' wall time runs until then)."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.last_end = inner, 0.0
        self.by_call: dict[str, float] = {}

    def __getattr__(self, name: str) -> Callable[..., Any]:
        call = getattr(self.inner, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return call(*args, **kwargs)
            finally:
                end = time.perf_counter()
                self.last_end = max(self.last_end, end)
                self.by_call[name] = self.by_call.get(name, 0.0) + end - t0

        return timed


def _phases(kube: Kube, ns: str, fleet: str, robot: str) -> dict[str, float]:
    """The plugin's steps in this process: API reads, build, explanation (seconds)."""
    from fogfleet.commandline.kubectl.cluster import connect as plugin_connect
    from fogfleet.commandline.kubectl.live import read_fleet
    from fogfleet.snapshot.live import why_of

    source = TimedSource(plugin_connect(str(kube.kubeconfig), None)[0])
    t0 = time.perf_counter()
    live = read_fleet(source, ns, fleet)
    t1 = time.perf_counter()
    why = why_of(live, MODULE, robot)
    t2 = time.perf_counter()
    assert why.instances and why.instances[0].alternatives, "the instance is explained"
    reads = {f"api_{name}_s": took for name, took in source.by_call.items()}
    api = source.last_end - t0
    return {"api_s": api, "build_s": t1 - t0 - api, "why_s": t2 - t1, **reads}


def bench(args: argparse.Namespace) -> list[Obj]:
    kube = connect(profile="kwok")  # the bed first: its heartbeats are relaxed once it runs
    with heartbeats.relaxed():
        return _bench(args, kube)


def _bench(args: argparse.Namespace, kube: Kube) -> list[Obj]:
    spec = large_spec(args.robots, args.edges)
    ns = f"bench-why-{secrets.token_hex(2)}"
    op = Operator(kube.kubeconfig, [ns], Path(tempfile.mkdtemp(prefix="fogfleet-why-")) / "op.log")
    robots = spec.fleet["spec"]["robots"]
    robot = robots[len(robots) // 2]
    versions: list[tuple[str, Path | None]] = [("this checkout", None), (LOCAL, None)]
    if args.baseline is not None:
        versions.append(("baseline", args.baseline))
    rows: dict[str, list[float]] = {name: [] for name, _ in versions}
    phases: list[dict[str, float]] = []
    try:
        setup_cluster(kube, [spec])
        # the namespace first, as a user's exists before the operator serves it (kopf's
        # namespace discovery can miss one created during its start: docs/limits.md)
        create_namespace(kube, ns)
        op.start().wait_live()
        server_side_apply(kube, spec.modules_in(ns), "fogfleet-bench")
        watcher = Watcher(kube, ns, spec.pods)
        try:
            server_side_apply(kube, [spec.fleet_in(ns)], "fogfleet-bench")
            watcher.wait(args.timeout)
        finally:
            watcher.close()
        log(f"{spec.pods} module pods Running; timing `kubectl fogfleet why` x{args.runs}")
        command = _command(kube, ns, spec.fleet_name, robot)
        imports = [_wall(["-m", "fogfleet.commandline.kubectl", "--help"], None)]
        for k in range(args.runs):
            for name, where in versions if k % 2 == 0 else versions[::-1]:
                argv = [*command, "--local"] if name == LOCAL else command
                rows[name].append(_wall(argv, where, answered=name == "this checkout"))
            phases.append(_phases(kube, ns, spec.fleet_name, robot))
            imports.append(_wall(["-m", "fogfleet.commandline.kubectl", "--help"], None))
    finally:
        teardown_cluster(kube, [ns])
        op.stop()
    answers = _answer_seconds(op.log_path)
    asked = {  # the asking command's: imports every command pays, the operator's answer
        "imports_s": round(statistics.median(imports), 2),
        "answer_s": round(statistics.median(answers), 3) if answers else None,
    }
    local = {k: round(statistics.median(p.get(k, 0.0) for p in phases), 3) for k in phases[0]}
    return [
        {
            "version": name if where is None else f"{name} ({where})",
            "robots": args.robots,
            "edges": args.edges,
            "instances": spec.pods,
            "runs": len(rows[name]),
            "why_s_median": round(statistics.median(rows[name]), 2),
            "why_s_min": round(min(rows[name]), 2),
            "why_s_max": round(max(rows[name]), 2),
            # in-process splits of this checkout's two ways
            **(asked if name == "this checkout" else local if name == LOCAL else {}),
        }
        for name, where in versions
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--edges", type=int, default=100)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds until all Running")
    ap.add_argument("--baseline", type=Path, help="an operator/ directory to compare with")
    ap.add_argument("--record", type=Path, help="write the result as JSON here")
    args = ap.parse_args(argv)
    result = bench(args)
    print(format_table(result))
    if args.record:
        words = argv if argv is not None else sys.argv[1:]
        command = ["python", "-m", "e2e.bench.why_live", *words]
        write_record(args.record, "why-live", result, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
