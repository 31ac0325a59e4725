"""The WAN relay (``wan.py``) on loopback: it never delivers before its delay, paces to its rate,
and a cut holds what crosses until the link returns (no cluster; a few seconds)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from e2e.bed.base import free_port

WAN = Path(__file__).with_name("wan.py")
DELAY_MS = 30.0


@pytest.fixture
def echo() -> Iterator[int]:
    """A loopback echo server; yields its port."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            threading.Thread(target=_echo, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    yield port
    server.close()


def _echo(conn: socket.socket) -> None:
    with conn:
        while data := conn.recv(65536):
            conn.sendall(data)


class Relay:
    def __init__(self, target: int, settings: Path) -> None:
        self.port, self.settings = free_port(), settings
        self.set(delay_ms=DELAY_MS)
        self.proc = subprocess.Popen(
            [sys.executable, str(WAN), f"--route=127.0.0.1:{self.port}=127.0.0.1:{target}",
             f"--settings={settings}"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.proc.stdout is not None
        while "->" not in self.proc.stdout.readline():  # listening
            assert self.proc.poll() is None, "wan.py exited"

    def set(self, **settings: object) -> None:
        self.settings.write_text(json.dumps(settings))
        if hasattr(self, "proc"):
            self.proc.send_signal(signal.SIGHUP)
            assert self.proc.stdout is not None
            self.proc.stdout.readline()  # "wan: up|CUT, ...": applied

    def stop(self) -> str:
        """Stop it; return what it wrote to stderr (nothing, when it stopped cleanly)."""
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=10)
        assert self.proc.stderr is not None
        return self.proc.stderr.read()


@pytest.fixture
def relay(echo: int, tmp_path: Path) -> Iterator[Relay]:
    r = Relay(echo, tmp_path / "wan.json")
    yield r
    assert r.stop() == ""  # a stop with connections open leaves no traceback


def _round_trip(port: int, payload: bytes = b"ping", timeout: float = 10.0) -> float:
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        t0 = time.monotonic()
        s.sendall(payload)
        got = b""
        while len(got) < len(payload):
            got += s.recv(65536)
        return time.monotonic() - t0


def test_a_round_trip_takes_at_least_the_delay_both_ways(relay: Relay) -> None:
    _round_trip(relay.port)  # the connection to the target is made
    rtts = [_round_trip(relay.port) for _ in range(3)]
    assert min(rtts) >= 2 * DELAY_MS / 1e3, rtts
    assert min(rtts) < 2 * DELAY_MS / 1e3 + 1.0, rtts  # held by the delay, not stuck


def test_the_rate_paces_what_crosses(relay: Relay) -> None:
    relay.set(delay_ms=0, rate_mbit=8)  # 1 MB/s
    # 0.5 MB each way; the echo streams back as it comes, so the two directions overlap and
    # the last byte cannot be back before 0.5 s
    took = _round_trip(relay.port, b"x" * 500_000)
    assert took >= 0.49, took


def test_a_cut_holds_everything_until_the_link_returns(relay: Relay) -> None:
    relay.set(delay_ms=0, cut=True)
    s = socket.create_connection(("127.0.0.1", relay.port), timeout=10)
    s.sendall(b"held")
    s.settimeout(0.5)
    with pytest.raises(TimeoutError):
        s.recv(16)  # nothing crosses while cut, on a connection made during the cut
    relay.set(delay_ms=0, cut=False)
    s.settimeout(10)
    assert s.recv(16) == b"held"
    s.close()


def test_the_relay_refuses_an_address_off_loopback(tmp_path: Path) -> None:
    (tmp_path / "wan.json").write_text("{}")
    out = subprocess.run(
        [sys.executable, str(WAN), "--route=0.0.0.0:1=127.0.0.1:2",
         f"--settings={tmp_path / 'wan.json'}"],
        capture_output=True, text=True, timeout=30, env=dict(os.environ),
    )  # fmt: skip
    assert out.returncode != 0 and "not on loopback" in out.stderr
