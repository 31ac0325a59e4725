"""Processes the harness starts: detached, pid + start time recorded, stopped by pid only."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from e2e.bed.base import STATE_DIR, log


def _proc_starttime(pid: int) -> str | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()
    if fields[0] == "Z":
        return None
    return fields[19]  # field 22 of /proc/pid/stat: start time in clock ticks


def _pid_file(name: str) -> Path:
    return STATE_DIR / "pids" / f"{name}.pid"


def _read_pid(name: str) -> dict[str, Any] | None:
    try:
        rec: dict[str, Any] = json.loads(_pid_file(name).read_text())
    except (OSError, ValueError):
        return None
    return rec


def _alive(name: str) -> int | None:
    """The pid of component `name` if that exact process (pid + start time) still runs."""
    rec = _read_pid(name)
    if rec is None:
        return None
    pid = int(rec["pid"])
    if _proc_starttime(pid) != rec.get("starttime"):
        return None
    return pid


def _start(name: str, argv: Sequence[str | Path], env: Mapping[str, str] | None = None) -> int:
    logs = STATE_DIR / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    (STATE_DIR / "pids").mkdir(parents=True, exist_ok=True)
    log_path = logs / f"{name}.log"
    with log_path.open("ab") as out:
        out.write(f"# {time.ctime()}: {' '.join(map(str, argv))}\n".encode())
        out.flush()
        proc = subprocess.Popen(
            [str(a) for a in argv],
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=STATE_DIR,
            env=dict(env) if env is not None else None,
            start_new_session=True,
        )
    rec = {"pid": proc.pid, "argv0": str(argv[0]), "starttime": _proc_starttime(proc.pid)}
    _pid_file(name).write_text(json.dumps(rec) + "\n")
    log(f"{name}: started pid {proc.pid} (log: {log_path})")
    return proc.pid


def _stop(name: str, grace: float = 10) -> None:
    pid = _alive(name)
    if pid is None:
        _pid_file(name).unlink(missing_ok=True)
        return
    rec = _read_pid(name) or {}
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and _proc_starttime(pid) == rec.get("starttime"):
        time.sleep(0.1)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)  # reap, when the caller is the parent (pytest)
    if _proc_starttime(pid) == rec.get("starttime"):
        log(f"{name}: pid {pid} ignored SIGTERM for {grace:.0f}s; sending SIGKILL")
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    log(f"{name}: stopped pid {pid}")
    _pid_file(name).unlink(missing_ok=True)


def log_tail(name: str, lines: int = 40) -> str:
    path = STATE_DIR / "logs" / f"{name}.log"
    try:
        with path.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 200 * lines))
            text = fh.read().decode(errors="replace")
    except OSError:
        return f"(no log at {path})"
    return "\n".join(text.splitlines()[-lines:])
