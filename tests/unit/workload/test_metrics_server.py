"""The workload's /metrics endpoint: keep-alive and gzip, so a scrape is one round trip."""

from __future__ import annotations

import gzip
import http.client
from collections.abc import Iterator

import pytest
from prometheus_client import generate_latest

from fogfleet.workload.metrics import WorkloadMetrics


@pytest.fixture
def endpoint() -> Iterator[tuple[WorkloadMetrics, int]]:
    metrics = WorkloadMetrics("detector", "robot-1", "robot")
    server = metrics.serve("127.0.0.1", 0)
    try:
        yield metrics, int(server.server_address[1])
    finally:
        server.shutdown()
        server.server_close()


def test_scrapes_reuse_one_connection(endpoint: tuple[WorkloadMetrics, int]) -> None:
    _, port = endpoint
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        for _ in range(3):
            conn.request("GET", "/metrics")
            resp = conn.getresponse()
            body = resp.read()
            assert resp.status == 200 and b"fogfleet_cycle_time_seconds" in body
            assert int(resp.getheader("Content-Length", "0")) == len(body)
        assert conn.sock is not None, "the server closed the connection after a scrape"
    finally:
        conn.close()


def test_gzip_when_the_scraper_accepts_it(endpoint: tuple[WorkloadMetrics, int]) -> None:
    _, port = endpoint
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.request("GET", "/metrics", headers={"Accept-Encoding": "gzip"})
        resp = conn.getresponse()
        packed = resp.read()
        assert resp.getheader("Content-Encoding") == "gzip"
        assert b"fogfleet_missed_cycles_total" in gzip.decompress(packed)
    finally:
        conn.close()


def test_healthz_and_unknown_paths(endpoint: tuple[WorkloadMetrics, int]) -> None:
    metrics, port = endpoint
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.request("GET", "/healthz")
        resp = conn.getresponse()
        assert (resp.status, resp.read()) == (200, b"ok\n")
        metrics.healthy = False
        conn.request("GET", "/healthz")
        resp = conn.getresponse()
        assert resp.status == 503 and resp.read() == b""
        conn.request("GET", "/nope")  # the same connection still answers
        assert conn.getresponse().status == 404
    finally:
        conn.close()


def test_execution_times_carry_the_row_they_belong_to() -> None:
    metrics = WorkloadMetrics("detector", "robot-1", "robot", "bed-robot", "100m")
    metrics.execution.observe(0.12)
    text = generate_latest(metrics.registry).decode()
    assert (
        'fogfleet_execution_time_seconds_count{cpu="100m",hardware_type="bed-robot",'
        'module="detector",robot="robot-1",tier="robot"} 1.0'
    ) in text


def test_the_work_factor_is_a_positive_number() -> None:
    import argparse

    from fogfleet.workload.__main__ import _work_factor

    assert _work_factor("4") == (4.0, "")
    assert _work_factor("2.5@bed-robot") == (2.5, "bed-robot")
    for bad in ("0", "-1", "1000", "x@bed-robot", "@bed-robot"):
        with pytest.raises(argparse.ArgumentTypeError):
            _work_factor(bad)


def _counts(text: str) -> tuple[float, float]:
    """(cycles, missed) in one exposition."""
    cycles = missed = 0.0
    for line in text.splitlines():
        if line.startswith("fogfleet_cycle_time_seconds_count"):
            cycles = float(line.rsplit(" ", 1)[1])
        elif line.startswith("fogfleet_missed_cycles_total"):
            missed = float(line.rsplit(" ", 1)[1])
    return cycles, missed


def test_a_scrape_never_sees_a_miss_without_its_cycle() -> None:
    """Every cycle here is missed, so every scrape must read missed == cycles (bench-real once
    measured an on-board window at 100.65 %: a scrape fell between a cycle and its miss)."""
    import threading

    metrics = WorkloadMetrics("detector", "robot-1", "robot")
    stop = threading.Event()

    def cycles() -> None:
        while not stop.is_set():
            metrics.cycle_done(0.2, 0.1)

    worker = threading.Thread(target=cycles)
    worker.start()
    try:
        seen = [_counts(metrics.exposition().decode()) for _ in range(300)]
    finally:
        stop.set()
        worker.join()
    assert seen[-1][0] > 0
    assert all(c == m for c, m in seen), [s for s in seen if s[0] != s[1]][:3]
