#!/usr/bin/env python3
"""A Zenoh router as a bed process (issue 47: ROS 2's data across the WAN, MULTICLUSTER.md 1.4).

    python e2e/bed/routers.py --listen tcp/127.0.0.1:P [--connect tcp/127.0.0.1:Q]

The cloud's router listens; the site's dials it across the WAN (``wan.py``), as a site behind
NAT dials out, and listens for the robots' relays (``fogfleet.workload.relay``) on loopback and
on the bed's bridge, where the real nodes' pods reach it. eclipse-zenoh runs the router
in-process (``zenoh.open`` in ``router`` mode); ``zenohd`` would do the same from Rust.
Scouting is off, multicast and gossip alike: routers and clients find each other only by the
endpoints given, so nothing is sent to a multicast group and nothing listens beyond loopback
and the bridge. Runs until SIGTERM.

Needs the venv's Python (eclipse-zenoh comes with the [ros] extra); the harness starts it so.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

__all__ = ["BRIDGE_ENDPOINT", "config", "main"]

# the bed's bridge (bednet.BRIDGE_IP; this script runs without the e2e package on its path):
# the site's router listens there too, for the robots' relays in the real nodes' pods
BRIDGE_ENDPOINT = "tcp/198.18.0.1:"


def config(mode: str, listen: Sequence[str] = (), connect: Sequence[str] = ()) -> Any:
    """A Zenoh config of the bed: ``mode`` (router, peer, client), the endpoints given, no
    scouting. Every Zenoh session of the bed (routers, tests' clients) is opened with it."""
    from fogfleet.workload.relay import zenoh_config

    for endpoint in (*listen, *connect):
        if not endpoint.startswith(("tcp/127.", BRIDGE_ENDPOINT)):
            raise ValueError(f"{endpoint}: the bed's Zenoh endpoints are tcp on loopback or on "
                             "the bed's bridge")  # fmt: skip
    return zenoh_config(mode, listen, connect)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="routers.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--listen", action="append", default=[], help="tcp/127.0.0.1:PORT")
    ap.add_argument("--connect", action="append", default=[], help="tcp/127.0.0.1:PORT")
    ns = ap.parse_args(argv)
    import zenoh

    session = zenoh.open(config("router", ns.listen, ns.connect))
    print(f"router {session.zid()}: listening on {ns.listen}, connecting to {ns.connect}",
          flush=True)  # fmt: skip
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
