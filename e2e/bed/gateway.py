#!/usr/bin/env python3
"""A TCP relay from the bed's bridge address to a loopback port (stdlib only).

    python3 e2e/bed/gateway.py 198.18.0.1:26443=127.0.0.1:26443 [more ...]

The control plane listens on 127.0.0.1 only; real nodes (kubelets, kube-proxy, in-cluster
clients through the ``kubernetes`` Service) reach the apiserver at the bridge address, which
exists only on the harness's own bridge. TLS passes through untouched (the apiserver's
certificate names the bridge address).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys

BUFFER = 64 * 1024


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(BUFFER):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


def _handler(target_host: str, target_port: int):  # type: ignore[no-untyped-def]
    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(target_host, target_port)
        except OSError:
            writer.close()
            return
        await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))

    return handle


def _split(addr: str) -> tuple[str, int]:
    host, _, port = addr.rpartition(":")
    return host, int(port)


async def serve(routes: list[tuple[str, str]]) -> None:
    servers = []
    for listen, target in routes:
        lh, lp = _split(listen)
        th, tp = _split(target)
        if not th.startswith("127."):
            raise SystemExit(f"gateway: target {target} is not on loopback")
        servers.append(await asyncio.start_server(_handler(th, tp), lh, lp, reuse_address=True))
        print(f"gateway: {listen} -> {target}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    for s in servers:
        s.close()


def main(argv: list[str]) -> int:
    routes = [tuple(arg.split("=", 1)) for arg in argv]
    if not routes or any(len(r) != 2 for r in routes):
        print(__doc__, file=sys.stderr)
        return 2
    asyncio.run(serve([(a, b) for a, b in routes]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
