"""The split benchmark on the default bed's real nodes (``protocol`` fixes what it does).

    make bench-split       # = python -m e2e.bench.split (starts the default bed when none runs)

The operator (``fogfleet run``, scoped to the bench's namespace) plans the split fleet once;
each run then sets the module's ``template.args`` to its arm (the operator re-renders the
pods), waits for robot-1's new head to answer frames, and measures one window per link
setting from that head's counters. ``bench-split.json`` is written after every run (a run that
fails keeps what was measured); the report prints the table and writes the docs page.
"""

from __future__ import annotations

import argparse
import json
import secrets
import shlex
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from e2e.bed import harness
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import fleet, pods_by_instance
from e2e.bench.real.run import connect
from e2e.bench.split import report
from e2e.bench.split.protocol import (
    ARM_ARGS,
    GAMMA_MS,
    LINKS,
    RUNS,
    WARMUP_S,
    WINDOW_S,
    Counters,
    Window,
    schedule,
    summary,
    verdict,
)
from e2e.faults.cost import metrics_url
from e2e.faults.cutfleet import fleet_pod
from e2e.portable.metrics import read
from e2e.tests.dnnbed import ALPHA_MS, FLEET, MODULE, head_action, split_objects
from e2e.tests.rosbed import EDGE, ROBOTS, operated_fleet
from fogfleet.bench.record import write_record

__all__ = ["main"]

ROBOT = ROBOTS[0]
BED_PROFILE = "default"
FIRST_FRAMES = 20  # a new head has answered this many frames: it runs


def log(msg: str) -> None:
    print(f"[bench-split {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def counters(url: str) -> Counters:
    """One scrape of a head's counters (OSError: not reachable)."""
    m = read(url)
    frames = "fogfleet_dnn_frames_total"
    return Counters(
        frames=m.total(frames),
        late=m.total("fogfleet_dnn_late_frames_total"),
        local=m.total(frames, by="local") + m.total(frames, by="local after timeout"),
        robot_s=m.total("fogfleet_dnn_robot_seconds_total"),
        frame_s=m.total("fogfleet_dnn_frame_seconds_sum"),
    )


def _head_pod(kube: Kube, ns: str) -> Any:
    return fleet_pod(pods_by_instance(kube, ns), ROBOT, MODULE, standby=True)


def set_arm(kube: Kube, ns: str, arm: str) -> str:
    """The module's pods run ``arm``; robot-1's head's metrics URL once it answers frames."""
    args = ARM_ARGS[arm]
    patch = json.dumps({"spec": {"template": {"args": args}}})
    kube.kubectl("patch", "softwaremodule", MODULE, "-n", ns, "--type=merge", "-p", patch)
    url = ""

    def answering() -> bool:
        nonlocal url
        try:
            pod = _head_pod(kube, ns)
        except AssertionError:
            return False
        if pod["spec"]["containers"][0].get("args", []) != args:
            return False
        url = metrics_url(pod)
        try:
            return counters(url).frames >= FIRST_FRAMES
        except OSError:
            return False

    kube.wait_for(f"robot-1's head running {arm}", answering, 240, 2)
    return url


def _planned(kube: Kube, ns: str) -> dict[str, Any]:
    """Robot-1's entry of the fleet's placement (node, split and its reason)."""
    for p in fleet(kube, ns, FLEET).get("status", {}).get("placement", []):
        if p.get("robot") == ROBOT and p.get("module") == MODULE:
            return {k: p.get(k) for k in ("node", "split")}
    return {}


def one_run(
    kube: Kube, cluster: harness.Cluster, ns: str, block: int, arm: str, warmup: float,
    window: float,
) -> list[Window]:  # fmt: skip
    """Arm ``arm``'s windows, one per link setting; robot-1's link is reset after."""
    url = set_arm(kube, ns, arm)
    out = []
    try:
        for link, change in LINKS.items():
            if change:
                cluster.set_link(ROBOT, **change)
            else:
                cluster.reset_link(ROBOT)
            time.sleep(warmup)
            before, t0 = counters(url), time.monotonic()
            time.sleep(window)
            after, seconds = counters(url), time.monotonic() - t0
            w = Window.between(
                before, after, block=block, arm=arm, link=link, seconds=seconds,
                cycle_s=ALPHA_MS / 1e3, action=head_action(url),
            )  # fmt: skip
            log(f"block {block} {arm} {link}: {w.frames:g} frames, {w.over_alpha:g} over alpha, "
                f"robot {w.robot_ms:.3g} ms a frame, head ran {w.action or '?'}")  # fmt: skip
            out.append(w)
    finally:
        cluster.reset_link(ROBOT)
    return out


def run_bench(
    kube: Kube, cluster: harness.Cluster, runs: int, warmup: float, window: float, out: Path,
    command: str,
) -> dict[str, Any]:  # fmt: skip
    """Every run of the schedule on a running default bed; the record written after each."""
    if not {*ROBOTS, EDGE} <= set(cluster.real_nodes):
        raise SystemExit(f"the split fleet needs the default bed's real nodes {(*ROBOTS, EDGE)}")
    ns = f"bench-split-{secrets.token_hex(2)}"
    kube.create_namespace(ns)
    workdir = Path(tempfile.mkdtemp(prefix="bench-split-"))
    log(f"namespace {ns}; operator log {workdir / 'operator.log'}")
    windows: list[Window] = []
    result: dict[str, Any] = {}
    t0 = time.monotonic()
    objects = split_objects(ns, maxRobotMillis=GAMMA_MS)
    try:
        with operated_fleet(kube, cluster, ns, workdir, [], objects, FLEET):
            planned = _planned(kube, ns)
            log(f"planned for robot-1: {planned}")
            for block, arm in schedule(runs):
                windows += one_run(kube, cluster, ns, block, arm, warmup, window)
                result = _result(windows, planned, runs, warmup, window, time.monotonic() - t0)
                write_record(out, report.SUITE, result, shlex.split(command))
    finally:
        kube.kubectl("delete", "namespace", ns, "--wait=false", "--ignore-not-found",
                     check=False)  # fmt: skip
    return result


def _result(
    windows: list[Window], planned: dict[str, Any], runs: int, warmup: float, window: float,
    seconds: float,
) -> dict[str, Any]:  # fmt: skip
    summ = summary(windows)
    return {
        "protocol": {
            "runs": runs,
            "warmupSeconds": warmup,
            "windowSeconds": window,
            "cycleMillis": ALPHA_MS,
            "gammaMillis": GAMMA_MS,
            "links": LINKS,
            "robot": ROBOT,
            "bed": BED_PROFILE,
        },
        "planned": planned,
        "windows": [w.as_json() for w in windows],
        "summary": summ,
        "verdict": verdict(summ),
        "totalSeconds": round(seconds),
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m e2e.bench.split", description=__doc__)
    ap.add_argument("--runs", type=int, default=RUNS, help="blocks (every arm once in each)")
    ap.add_argument("--warmup", type=float, default=WARMUP_S, help="seconds before a window")
    ap.add_argument("--window", type=float, default=WINDOW_S, help="seconds measured")
    ap.add_argument("--json", type=Path, default=Path("bench-split.json"), help="the record")
    ap.add_argument("--docs", type=Path, default=None, help="also write the docs page here")
    ns = ap.parse_args(argv)
    if ns.runs < 1 or ns.window <= 0 or ns.warmup < 0:
        ap.error("--runs must be >= 1, --window > 0 and --warmup >= 0")
    command = "python -m e2e.bench.split " + shlex.join(sys.argv[1:] if argv is None else argv)
    kube, cluster = connect(BED_PROFILE)
    run_bench(kube, cluster, ns.runs, ns.warmup, ns.window, ns.json, command.strip())
    report_args = ["--json", str(ns.json)] + ([] if ns.docs is None else ["--docs", str(ns.docs)])
    return report.main(report_args)
