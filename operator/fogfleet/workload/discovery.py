"""The robot's Fast DDS discovery server, from the ros-fastdds wheel in this environment.

Runs ``fast-discovery-server`` (the binary behind ``fastdds discovery``) directly: the shell
wrapper of the wheel picks whatever ``python3`` is first on PATH, and the binary needs the
wheel's bundled libraries on LD_LIBRARY_PATH for this process only.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["discovery_command", "run_discovery_server"]


def discovery_command(
    listen: str = "0.0.0.0", port: int = 11811, tcp_port: int | None = None
) -> tuple[list[str], dict[str, str]]:
    prefix = Path(sys.prefix)
    binary = prefix / "bin" / "fast-discovery-server"
    if not binary.exists():
        raise FileNotFoundError(f"{binary}: install the ros-fastdds wheel (the [ros] extra)")
    libs = [prefix / "lib", *sorted(prefix.glob("lib/python3*/site-packages/ros_fastdds.libs"))]
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = ":".join([*map(str, libs), env.get("LD_LIBRARY_PATH", "")]).rstrip(":")
    # 42 is the tool's "server" command (tools/fastdds/discovery/parser.py)
    argv = [str(binary), "42", "-l", listen, "-p", str(port)]
    if tcp_port:  # a TCP listener too: what the kubelet's probes check
        argv += ["-t", listen, "-q", str(tcp_port)]
    return argv, env


def run_discovery_server(
    listen: str = "0.0.0.0", port: int = 11811, tcp_port: int | None = None
) -> None:
    argv, env = discovery_command(listen, port, tcp_port)
    os.execve(argv[0], argv, env)
