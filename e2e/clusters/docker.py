"""Whether Docker can run a kind or k3d cluster here, asked before anything is created.

kind's and k3s's node containers run privileged (systemd or k3s, containerd, kubelet inside;
kind also raises resource limits, which needs CAP_SYS_RESOURCE). A Docker engine that cannot
start a privileged container makes either tool fail half-way with a cluster left behind; the
check starts one of the node image itself (``--network none``, so it reaches nothing) and
refuses with Docker's own words instead.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable, Sequence

__all__ = ["Refused", "check"]

Runner = Callable[[Sequence[str]], subprocess.CompletedProcess[str]]


class Refused(Exception):
    """This machine cannot run the cluster; the message is the one line the target prints."""


def _run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=600, check=False)


def _said(proc: subprocess.CompletedProcess[str]) -> str:
    lines = [ln.strip() for ln in (proc.stderr or proc.stdout or "").splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit status {proc.returncode}"


def check(
    provider: str,
    image: str,
    *,
    docker: str = "docker",
    run: Runner = _run,
    which: Callable[[str], str | None] = shutil.which,
) -> None:
    """Raise :class:`Refused` unless ``docker`` reaches an engine that starts ``image``
    privileged and ``provider`` (kind or k3d) is on PATH; the engine is asked first, as no
    tool helps without it."""
    if which(docker) is None:
        raise Refused(f"make e2e-{provider}: '{docker}' is not on PATH (this target needs Docker)")
    info = run([docker, "info", "--format", "{{.ServerVersion}}"])
    if info.returncode != 0:
        raise Refused(f"make e2e-{provider}: the Docker engine is not reachable: {_said(info)}")
    probe = run([docker, "run", "--rm", "--privileged", "--network", "none",
                 "--entrypoint", "true", image])  # fmt: skip
    if probe.returncode != 0:
        raise Refused(
            f"make e2e-{provider}: Docker cannot start a privileged container of {image}, which "
            f"{provider} needs for its nodes: {_said(probe)}"
        )
    if which(provider) is None:
        raise Refused(f"make e2e-{provider}: '{provider}' is not on PATH (this target needs it)")
