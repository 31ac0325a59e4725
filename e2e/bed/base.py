"""Shared ground of the e2e harness: paths, errors, logging, subprocesses, locking, waiting.

Stdlib only, so every harness module runs with any python3 >= 3.11.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import ssl
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TextIO

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parent.parent
VERSIONS_FILE = HERE / "versions.env"
NODES_FILE = HERE / "nodes.yaml"

CACHE_ROOT = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fogfleet"
TOOLS_DIR = CACHE_ROOT / "tools"
BIN_DIR = CACHE_ROOT / "bin"
STATE_DIR = CACHE_ROOT / "cluster"
KUBECONFIG = STATE_DIR / "kubeconfig"
PROMETHEUS_TARGETS_DIR = STATE_DIR / "prometheus-targets"
LOCK_FILE = CACHE_ROOT / "harness.lock"

HOST = "127.0.0.1"


class HarnessError(RuntimeError):
    """Anything that stops the harness: missing toolchain, registry outage, unhealthy process."""


_T0 = time.monotonic()


def log(msg: str) -> None:
    print(f"[harness {time.monotonic() - _T0:6.1f}s] {msg}", file=sys.stderr, flush=True)


def load_versions(path: Path = VERSIONS_FILE) -> dict[str, str]:
    versions: dict[str, str] = {}
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise HarnessError(f"{path}: bad line {raw!r}")
        versions[key.strip()] = value.strip()
    return versions


# A command that runs longer than this says so, again every PROGRESS_SECONDS: the step, the time
# it has taken and its last line of output (a Go build's package, apt's package, buildah's step).
PROGRESS_SECONDS = 20.0


def run(
    cmd: Sequence[str | os.PathLike[str]],
    *,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
    log_file: Path | None = None,
    timeout: float | None = None,
    hint: str = "",
) -> str:
    """Run a command, return stdout+stderr; on failure raise HarnessError with the output tail.

    The output goes to ``log_file`` line by line as the command writes it (``tail -f`` works
    during a build), and a command still running after ``PROGRESS_SECONDS`` logs a progress
    line that often, so no step of a build is silent for longer.
    """
    argv = [str(c) for c in cmd]
    step = f"{Path(argv[0]).name} {_verb(argv[1:])}".strip()  # "go build", "buildah bud"
    try:
        proc = subprocess.Popen(
            argv,
            cwd=cwd,
            env=dict(env) if env is not None else None,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
        )
    except FileNotFoundError as exc:
        raise HarnessError(f"command not found: {argv[0]} {hint}".strip()) from exc
    lines: list[str] = []
    with contextlib.ExitStack() as stack:
        sink = stack.enter_context(log_file.open("a")) if log_file is not None else None
        if sink is not None:
            sink.write(f"$ {' '.join(argv)}\n")
            sink.flush()
        pump = threading.Thread(target=_pump, args=(proc, lines, sink), daemon=True)
        pump.start()
        t0 = time.monotonic()
        while pump.is_alive():
            pump.join(PROGRESS_SECONDS)
            elapsed = time.monotonic() - t0
            if timeout is not None and elapsed > timeout:
                proc.kill()  # our child, by its pid
                proc.wait()
                raise HarnessError(f"timed out after {timeout}s: {' '.join(argv)}")
            if pump.is_alive():
                last = lines[-1].strip()[:120] if lines else "(no output yet)"
                log(f"... {step}: {elapsed:.0f}s so far; last output: {last}")
        returncode = proc.wait()
    out = "".join(lines)
    if returncode != 0:
        tail = "\n".join(out.splitlines()[-40:])
        raise HarnessError(
            f"command failed (exit {returncode}): {' '.join(argv)}\n{tail}\n{hint}".rstrip()
        )
    return out


def _verb(args: Sequence[str]) -> str:
    """The subcommand of a command line: its first word that is neither an option, an option's
    value (``--root /x``, ``--storage-driver overlay``) nor a path."""
    skip = False
    for a in args:
        if skip:
            skip = False
        elif a.startswith("--"):
            skip = "=" not in a
        elif not a.startswith("-") and "/" not in a:
            return a
    return ""


def _pump(proc: subprocess.Popen[str], lines: list[str], sink: TextIO | None) -> None:
    """Read the command's output as it comes: keep it, and write it through to the log."""
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line)
        if sink is not None:
            sink.write(line)
            sink.flush()


def kubectl(
    binary: str | Path,
    kubeconfig: Path,
    *args: str,
    input: str | None = None,
    check: bool = True,
    timeout: float = 120,
    error: type[Exception] = HarnessError,
) -> subprocess.CompletedProcess[str]:
    """The e2e suite's one kubectl runner (stdout/stderr captured as text); a failure with
    ``check`` raises ``error`` naming the command, its exit code and its output."""
    proc = subprocess.run(
        [str(binary), f"--kubeconfig={kubeconfig}", *args],
        input=input, capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip
    if check and proc.returncode != 0:
        raise error(
            f"kubectl {' '.join(args)} exited {proc.returncode}:\n{proc.stderr}{proc.stdout}"
        )
    return proc


@contextlib.contextmanager
def locked(lock_file: Path = LOCK_FILE) -> Iterator[None]:
    """Serialise build/up/down across processes (two pytest sessions, make in another shell);
    another ``lock_file`` serialises something else (the builds' apt-get)."""
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    with lock_file.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def wait_for(
    what: str,
    check: Callable[[], bool],
    timeout: float,
    interval: float = 0.5,
    fatal: tuple[type[Exception], ...] = (),
) -> None:
    """Poll ``check`` until it holds; a wait longer than ``PROGRESS_SECONDS`` says so that often.
    A probe that raises counts as "not yet", unless it raises one of ``fatal`` (a process that
    exited: no use waiting), which goes to the caller at once."""
    t0 = time.monotonic()
    deadline, report = t0 + timeout, t0 + PROGRESS_SECONDS
    while True:
        try:
            if check():
                return
        except fatal:
            raise
        except Exception:  # a probe that raises counts as "not yet"
            pass
        now = time.monotonic()
        if now > deadline:
            raise HarnessError(f"timed out after {timeout:.0f}s waiting for {what}")
        if now > report:
            log(f"... waiting for {what}: {now - t0:.0f}s of at most {timeout:.0f}s")
            report = now + PROGRESS_SECONDS
        time.sleep(interval)


def http_get(url: str, *, context: ssl.SSLContext | None = None, timeout: float = 3) -> str:
    with urllib.request.urlopen(url, context=context, timeout=timeout) as resp:
        body: bytes = resp.read()
        return body.decode()


def insecure_tls() -> ssl.SSLContext:
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    return ctx


def answers(host: str, port: int) -> bool:
    """Whether something accepts a TCP connection on ``host:port`` (OSError if not: a
    ``wait_for`` check)."""
    socket.create_connection((host, port), timeout=1).close()
    return True


def port_is_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        # as the Go servers do: a port in TIME_WAIT from a previous run counts as free
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((HOST, port))
        except OSError:
            return False
        return True


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        port: int = s.getsockname()[1]
        return port
