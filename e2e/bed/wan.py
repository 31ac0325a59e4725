#!/usr/bin/env python3
"""The WAN between the site and the cloud: a TCP relay on loopback that delays, paces and cuts
(stdlib only).

    python3 e2e/bed/wan.py --route 127.0.0.1:P=127.0.0.1:Q [--route ...] --settings FILE

Everything of the site that talks to the cloud dials one of the relay's ports instead of the
cloud's (issue 47: the site's OCM agent to the hub's API, the site's Zenoh router to the
cloud's), so that what crosses between them crosses this link and nothing else does. Each
direction holds each chunk for the one-way delay, in arrival order (nothing overtakes), and
paces the bytes to the rate. A cut holds everything:
the bytes in flight and new connections (accepted by the kernel on loopback, not passed on)
wait until the link returns, as TCP's retransmissions would carry them; a client whose own
timeouts run out first gives up, as over a real cut.

Why a relay and not the real nodes' links (``links``: tbf and a delay line in a network
namespace): the site's agent must reach its own cluster's API without crossing the WAN, and
only the cloud across it; a relay puts the link on exactly that path, on loopback.

SIGHUP re-reads ``--settings`` (JSON ``{"delay_ms": .., "rate_mbit": .., "cut": ..}``), so the
harness changes or cuts a running link (``set_link``) without restarting it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

BUFFER = 16 * 1024


@dataclass
class Link:
    delay_s: float = 0.0
    rate_bytes_s: float = 0.0  # 0: unpaced
    up: asyncio.Event | None = None

    def load(self, settings: Path) -> None:
        doc = json.loads(settings.read_text())
        self.delay_s = float(doc.get("delay_ms", 0.0)) / 1e3
        self.rate_bytes_s = float(doc.get("rate_mbit", 0.0)) * 1e6 / 8
        assert self.up is not None
        if doc.get("cut"):
            self.up.clear()
        else:
            self.up.set()
        state = "CUT" if doc.get("cut") else "up"
        print(f"wan: {state}, {self.delay_s * 1e3:g} ms one way, "
              f"{self.rate_bytes_s * 8 / 1e6:g} Mbit/s", flush=True)  # fmt: skip


async def _direction(
    reader: asyncio.StreamReader, writer: asyncio.StreamWriter, link: Link
) -> None:
    """Read as it comes; deliver each chunk after the delay, paced, in order, when the link is
    up."""
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def read() -> None:
        try:
            while data := await reader.read(BUFFER):
                await queue.put((time.monotonic(), data))
        except (ConnectionError, OSError):
            pass
        await queue.put((time.monotonic(), b""))

    async def deliver() -> None:
        assert link.up is not None
        free_at = 0.0  # when the pacer's line is free again
        try:
            while True:
                sent_at, data = await queue.get()
                await link.up.wait()
                wait = sent_at + link.delay_s - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                if link.rate_bytes_s > 0 and data:
                    free_at = max(free_at, time.monotonic()) + len(data) / link.rate_bytes_s
                    await asyncio.sleep(max(0.0, free_at - time.monotonic()))
                await link.up.wait()  # cut while it waited: held until the link returns
                if not data:
                    break
                writer.write(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            with contextlib.suppress(Exception):
                writer.close()

    await asyncio.gather(read(), deliver())


def _handler(target: tuple[str, int], link: Link, tasks: set[asyncio.Task[None]]):  # type: ignore[no-untyped-def]
    async def relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert link.up is not None
        await link.up.wait()  # a connection made during a cut reaches nothing until it ends
        try:
            up_reader, up_writer = await asyncio.open_connection(*target)
        except OSError:
            writer.close()
            return
        await asyncio.gather(
            _direction(reader, up_writer, link), _direction(up_reader, writer, link)
        )

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        # the relay runs as a task of its own, cancelled at the end; this one (asyncio's, per
        # connection) then ends normally: a cancelled one prints a traceback on Python 3.11
        task = asyncio.create_task(relay(reader, writer))
        tasks.add(task)
        try:
            await task
        except asyncio.CancelledError:
            pass
        finally:
            tasks.discard(task)

    return handle


def _split(addr: str) -> tuple[str, int]:
    host, _, port = addr.rpartition(":")
    if not host.startswith("127."):
        raise SystemExit(f"wan: {addr} is not on loopback")
    return host, int(port)


async def serve(routes: list[tuple[str, str]], settings: Path) -> None:
    """Relay each ``(listen, target)`` of ``routes`` over one link: one delay, one rate (per
    connection and direction), one cut."""
    link = Link(up=asyncio.Event())
    link.load(settings)
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGHUP, link.load, settings)
    tasks: set[asyncio.Task[None]] = set()
    servers = []
    for listen, target in routes:
        handler = _handler(_split(target), link, tasks)
        servers.append(await asyncio.start_server(handler, *_split(listen), reuse_address=True))
        print(f"wan: {listen} -> {target}", flush=True)
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    for server in servers:
        server.close()
    relays = list(tasks)
    for task in relays:
        task.cancel()
    await asyncio.gather(*relays, return_exceptions=True)
    await asyncio.sleep(0.05)  # the connections' own tasks end after their relays


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="wan.py", description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--route",
        action="append",
        required=True,
        metavar="LISTEN=TARGET",
        help="127.0.0.1:PORT the site dials = 127.0.0.1:PORT of the cloud's service (repeatable)",
    )
    ap.add_argument("--settings", required=True, type=Path, help="JSON: delay_ms, rate_mbit, cut")
    ns = ap.parse_args(argv)
    routes = [tuple(r.split("=", 1)) for r in ns.route]
    if any(len(r) != 2 for r in routes):
        ap.error("--route takes LISTEN=TARGET")
    asyncio.run(serve([(a, b) for a, b in routes], ns.settings))
    return 0


if __name__ == "__main__":
    sys.exit(main())
