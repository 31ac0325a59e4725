"""``make test-stress``: the unit and integration tiers, several times in random order, while
every core is kept busy by a burner this script starts and stops itself (issue 50).

A verdict that changes with the machine's load or with the order tests run in is a bug in the
test: this is how it is found before CI finds it. Each run is ``pytest`` over both tiers with
pytest-random-order (a new seed per run, printed, so a failure is reproduced with
``--random-order-seed``) and the unit tier's CPU guard on (``FOGFLEET_STRICT_UNIT=1``). The
burner is one busy-looping process per core, stopped by its pid when the runs end.

    python tests/stress/run.py [--runs 5] [--burners N] [--bucket global] [PYTEST ARGS ...]

Prints one row per run and a total; exits 1 when any run failed.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LOGS = REPO / "out" / "stress"  # each run's whole output (out/ is git-ignored)
TIERS = ("tests/unit", "tests/integration")
BURN = "while True: pass"
SUMMARY = re.compile(r"^=*\s*(\d+ (?:passed|failed|errors?|skipped).*) in [0-9.]+s")
COUNT = re.compile(r"(\d+) (passed|failed|errors?|skipped)")


@dataclass(frozen=True)
class Run:
    number: int
    seed: int
    exit_code: int
    counts: dict[str, int]
    seconds: float
    failures: tuple[str, ...]


@contextmanager
def burners(n: int) -> Iterator[list[int]]:
    """``n`` busy-looping processes for the block's length; stopped by pid, never by name."""
    procs = [
        subprocess.Popen([sys.executable, "-c", BURN], stdin=subprocess.DEVNULL) for _ in range(n)
    ]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                os.kill(p.pid, signal.SIGKILL)
            p.wait()


def run_once(number: int, seed: int, bucket: str, extra: Sequence[str]) -> Run:
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        *TIERS,
        "-q",
        "-p",
        "no:cacheprovider",
        f"--random-order-bucket={bucket}",
        f"--random-order-seed={seed}",
        *extra,
    ]
    env = {**os.environ, "FOGFLEET_STRICT_UNIT": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, check=False)
    seconds = time.monotonic() - t0
    out = proc.stdout + proc.stderr
    LOGS.mkdir(parents=True, exist_ok=True)
    (LOGS / f"run-{number}.log").write_text(out)
    counts: dict[str, int] = {}
    summary = next(
        (m.group(1) for line in reversed(out.splitlines()) if (m := SUMMARY.match(line))), ""
    )
    for n, what in COUNT.findall(summary):
        counts["errors" if what.startswith("error") else what] = int(n)
    failures = tuple(
        line.split(" ", 1)[1].split(" - ")[0]
        for line in out.splitlines()
        if line.startswith(("FAILED ", "ERROR "))
    )
    return Run(number, seed, proc.returncode, counts, seconds, failures)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument(
        "--burners",
        type=int,
        default=os.cpu_count() or 2,
        help="busy processes (default: one per core)",
    )
    parser.add_argument(
        "--bucket",
        default="global",
        help="pytest-random-order's bucket: global, package, module, class",
    )
    args, extra = parser.parse_known_args(argv)
    print(
        f"test-stress: {args.runs} runs of {' + '.join(TIERS)} in random order "
        f"(bucket {args.bucket}), {args.burners} burner(s) keeping the cores busy",
        flush=True,
    )
    runs: list[Run] = []
    with burners(args.burners) as pids:
        print(f"test-stress: burner pids {pids}", flush=True)
        for k in range(1, args.runs + 1):
            seed = random.SystemRandom().randrange(1, 10**6)
            run = run_once(k, seed, args.bucket, extra)
            runs.append(run)
            c = run.counts
            print(
                f"run {k}: seed {seed:>6}  {c.get('passed', 0)} passed, "
                f"{c.get('failed', 0) + c.get('errors', 0)} failed, {c.get('skipped', 0)} "
                f"skipped  {run.seconds:6.0f} s  (log out/stress/run-{k}.log)",
                flush=True,
            )
            for name in run.failures:
                print(f"    FAILED {name}  (--random-order-seed={seed})", flush=True)
    bad = [r for r in runs if r.exit_code != 0]
    passed = sum(r.counts.get("passed", 0) for r in runs)
    failed = sum(r.counts.get("failed", 0) + r.counts.get("errors", 0) for r in runs)
    print(
        f"test-stress: {len(runs) - len(bad)} of {len(runs)} runs green; "
        f"{passed} passed, {failed} failed in all",
        flush=True,
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
