#!/usr/bin/env python3
"""A userspace delay line on NFQUEUE (stdlib only): delay and jitter where netem is missing.

    python3 e2e/bed/delayline.py --queue 1 --delay-ms 4 --jitter-ms 1 [--seed 1]

Run inside a node's network namespace. iptables sends the packets crossing the node's link to
queue N (``-j NFQUEUE --queue-num N --queue-bypass``: with no listener they pass undelayed);
this process holds each verdict for delay + N(0, jitter) milliseconds and then accepts it, in
arrival order (a packet never overtakes the one before it, as on a real link). It speaks
nfnetlink_queue directly over a netlink socket and copies only packet metadata, never payload.

SIGHUP re-reads ``--settings FILE`` (JSON ``{"delay_ms": .., "jitter_ms": ..}``), so the
harness changes a running link without losing packets.
"""

from __future__ import annotations

import argparse
import contextlib
import heapq
import json
import os
import random
import select
import signal
import socket
import struct
import sys
import time
from pathlib import Path

NETLINK_NETFILTER = 12
NFNL_SUBSYS_QUEUE = 3
NFQNL_MSG_PACKET, NFQNL_MSG_VERDICT, NFQNL_MSG_CONFIG = 0, 1, 2
NFQA_CFG_CMD, NFQA_CFG_PARAMS, NFQA_CFG_QUEUE_MAXLEN = 1, 2, 3
NFQA_PACKET_HDR, NFQA_VERDICT_HDR = 1, 2
NFQNL_CFG_CMD_BIND, NFQNL_CFG_CMD_PF_BIND, NFQNL_CFG_CMD_PF_UNBIND = 1, 3, 4
NFQNL_COPY_META = 1
NF_ACCEPT = 1
NLM_F_REQUEST, NLM_F_ACK = 1, 4
NLMSG_ERROR = 2
QUEUE_MAXLEN = 16384


def _attr(kind: int, payload: bytes) -> bytes:
    length = 4 + len(payload)
    return struct.pack("=HH", length, kind) + payload + b"\0" * ((4 - length % 4) % 4)


def _message(msg: int, queue: int, attrs: bytes, flags: int = NLM_F_REQUEST, seq: int = 0) -> bytes:
    body = struct.pack("=BBH", socket.AF_INET, 0, socket.htons(queue)) + attrs
    kind = (NFNL_SUBSYS_QUEUE << 8) | msg
    return struct.pack("=IHHII", 16 + len(body), kind, flags, seq, 0) + body


def _attrs(data: bytes) -> dict[int, bytes]:
    out, i = {}, 0
    while i + 4 <= len(data):
        length, kind = struct.unpack_from("=HH", data, i)
        if length < 4:
            break
        out[kind & 0x7FFF] = data[i + 4 : i + length]
        i += (length + 3) & ~3
    return out


class Queue:
    """One bound nfnetlink queue."""

    def __init__(self, num: int) -> None:
        self.num = num
        self.sock = socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, NETLINK_NETFILTER)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind((0, 0))
        self._seq = 0
        cmd = NFQA_CFG_CMD
        self._config(0, _attr(cmd, struct.pack("!BBH", NFQNL_CFG_CMD_PF_UNBIND, 0, socket.AF_INET)))
        self._config(0, _attr(cmd, struct.pack("!BBH", NFQNL_CFG_CMD_PF_BIND, 0, socket.AF_INET)))
        self._config(num, _attr(cmd, struct.pack("!BBH", NFQNL_CFG_CMD_BIND, 0, socket.AF_INET)))
        self._config(num, _attr(NFQA_CFG_PARAMS, struct.pack("!IB", 0, NFQNL_COPY_META)))
        self._config(num, _attr(NFQA_CFG_QUEUE_MAXLEN, struct.pack("!I", QUEUE_MAXLEN)))

    def _config(self, queue: int, attrs: bytes) -> None:
        self._seq += 1
        self.sock.send(
            _message(NFQNL_MSG_CONFIG, queue, attrs, NLM_F_REQUEST | NLM_F_ACK, self._seq)
        )
        reply = self.sock.recv(65536)
        _, kind = struct.unpack_from("=IH", reply, 0)
        if kind == NLMSG_ERROR:
            (err,) = struct.unpack_from("=i", reply, 16)
            if err not in (0, -16):  # -EBUSY on PF_UNBIND of an unbound family is harmless
                raise OSError(-err, f"nfqueue config failed: {os.strerror(-err)}")

    def packets(self) -> list[int]:
        """Ids of the packets waiting on the socket (non-blocking drain)."""
        ids = []
        while True:
            try:
                data = self.sock.recv(262144, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return ids
            except OSError:  # ENOBUFS: the kernel dropped queue messages; keep going
                return ids
            i = 0
            while i + 16 <= len(data):
                length, kind = struct.unpack_from("=IH", data, i)
                if length < 16:
                    break
                if kind == (NFNL_SUBSYS_QUEUE << 8) | NFQNL_MSG_PACKET:
                    hdr = _attrs(data[i + 20 : i + length]).get(NFQA_PACKET_HDR)
                    if hdr is not None:
                        ids.append(struct.unpack_from("!I", hdr, 0)[0])
                i += (length + 3) & ~3

    def accept(self, packet_id: int) -> None:
        attrs = _attr(NFQA_VERDICT_HDR, struct.pack("!II", NF_ACCEPT, packet_id))
        self.sock.send(_message(NFQNL_MSG_VERDICT, self.num, attrs))


def run(queue: Queue, delay_ms: float, jitter_ms: float, settings: Path | None, seed: int) -> None:
    rng = random.Random(seed)
    held: list[tuple[float, int, int]] = []  # (release time, arrival order, packet id)
    order = 0
    last_release = 0.0
    params = {"delay_ms": delay_ms, "jitter_ms": jitter_ms}
    reload = False
    stop = False

    def on_hup(*_: object) -> None:
        nonlocal reload
        reload = True

    def on_term(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGHUP, on_hup)
    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    while not stop:
        if reload and settings is not None:
            reload = False
            try:
                params.update(json.loads(settings.read_text()))
            except (OSError, ValueError) as exc:
                print(f"delayline: bad settings: {exc}", file=sys.stderr, flush=True)
        now = time.monotonic()
        timeout = max(0.0, held[0][0] - now) if held else 0.5
        try:
            ready, _, _ = select.select([queue.sock], [], [], timeout)
        except InterruptedError:
            continue
        now = time.monotonic()
        if ready:
            base = params["delay_ms"] / 1000.0
            spread = params["jitter_ms"] / 1000.0
            for packet_id in queue.packets():
                sample = base + (rng.gauss(0.0, spread) if spread > 0 else 0.0)
                release = max(now + max(sample, 0.0), last_release)
                last_release = release
                heapq.heappush(held, (release, order, packet_id))
                order += 1
        while held and held[0][0] <= time.monotonic():
            _, _, packet_id = heapq.heappop(held)
            with contextlib.suppress(OSError):
                queue.accept(packet_id)
    for _, _, packet_id in held:  # let what is in flight go on
        with contextlib.suppress(OSError):
            queue.accept(packet_id)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--queue", type=int, required=True)
    parser.add_argument("--delay-ms", type=float, default=0.0)
    parser.add_argument("--jitter-ms", type=float, default=0.0)
    parser.add_argument("--settings", type=Path)
    parser.add_argument("--seed", type=int, default=1)
    ns = parser.parse_args(argv)
    if ns.settings is not None and ns.settings.exists():
        cfg = json.loads(ns.settings.read_text())
        ns.delay_ms, ns.jitter_ms = (
            cfg.get("delay_ms", ns.delay_ms),
            cfg.get("jitter_ms", ns.jitter_ms),
        )
    queue = Queue(ns.queue)
    print(f"delayline: queue {ns.queue}, {ns.delay_ms} ms ± {ns.jitter_ms} ms", flush=True)
    run(queue, ns.delay_ms, ns.jitter_ms, ns.settings, ns.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
