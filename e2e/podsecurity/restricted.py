"""The "restricted" Pod Security Standard, as rules on a pod spec: what the PodSecurity
admission plugin checks at ``pod-security.kubernetes.io/enforce: restricted``.

From https://kubernetes.io/docs/concepts/security/pod-security-standards/ (the baseline
controls, which restricted includes, then restricted's own). Each rule returns one line per
violation, naming the container; ``violations(pod_spec)`` is all of them. Pure, so the unit
test (tests/unit/render/test_pod_security.py) checks what ``fogfleet render`` prints and the
e2e test (e2e/tests/test_faults_pod_security.py) lets the real admission plugin judge the same.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

__all__ = ["violations"]

Obj = dict[str, Any]

# baseline: "Capabilities" (the allowed adds); restricted: only NET_BIND_SERVICE may be added
RESTRICTED_ADDS = {"NET_BIND_SERVICE"}
# restricted: "Volume Types"
RESTRICTED_VOLUMES = {
    "configMap",
    "csi",
    "downwardAPI",
    "emptyDir",
    "ephemeral",
    "persistentVolumeClaim",
    "projected",
    "secret",
}
SECCOMP_OK = {"RuntimeDefault", "Localhost"}
SAFE_SYSCTLS = {
    "kernel.shm_rmid_forced",
    "net.ipv4.ip_local_port_range",
    "net.ipv4.ip_unprivileged_port_start",
    "net.ipv4.tcp_syncookies",
    "net.ipv4.ping_group_range",
    "net.ipv4.ip_local_reserved_ports",
    "net.ipv4.tcp_keepalive_time",
    "net.ipv4.tcp_fin_timeout",
    "net.ipv4.tcp_keepalive_intvl",
    "net.ipv4.tcp_keepalive_probes",
}


def _containers(spec: Obj) -> Iterator[Obj]:
    for key in ("initContainers", "containers", "ephemeralContainers"):
        yield from spec.get(key) or ()


def _baseline(spec: Obj) -> Iterator[str]:
    for key in ("hostNetwork", "hostPID", "hostIPC"):  # "Host Namespaces"
        if spec.get(key):
            yield f"{key}: true"
    pod_sc = spec.get("securityContext") or {}
    for sysctl in pod_sc.get("sysctls") or ():  # "Sysctls"
        if sysctl.get("name") not in SAFE_SYSCTLS:
            yield f"unsafe sysctl {sysctl.get('name')}"
    for vol in spec.get("volumes") or ():  # "HostPath Volumes"
        if "hostPath" in vol:
            yield f"hostPath volume {vol.get('name')}"
    for c in _containers(spec):
        sc = c.get("securityContext") or {}
        name = c.get("name")
        if sc.get("privileged"):  # "Privileged Containers"
            yield f"{name}: privileged"
        for port in c.get("ports") or ():  # "Host Ports"
            if port.get("hostPort"):
                yield f"{name}: hostPort {port['hostPort']}"
        if sc.get("procMount", "Default") != "Default":  # "/proc Mount Type"
            yield f"{name}: procMount {sc['procMount']}"


def _seccomp(sc: Obj) -> str | None:
    profile = sc.get("seccompProfile") or {}
    return profile.get("type")


def _restricted(spec: Obj) -> Iterator[str]:
    for vol in spec.get("volumes") or ():  # "Volume Types"
        kinds = set(vol) - {"name"}
        if not kinds <= RESTRICTED_VOLUMES:
            yield f"volume {vol.get('name')} of type {sorted(kinds - RESTRICTED_VOLUMES)}"
    pod_sc = spec.get("securityContext") or {}
    if pod_sc.get("runAsUser") == 0:  # "Running as Non-root user"
        yield "pod runAsUser: 0"
    for c in _containers(spec):
        sc = c.get("securityContext") or {}
        name = c.get("name")
        if sc.get("allowPrivilegeEscalation") is not False:  # "Privilege Escalation"
            yield f"{name}: allowPrivilegeEscalation is not false"
        # "Running as Non-root": set on the container or the pod, never false on the container
        if sc.get("runAsNonRoot") is False or not (
            sc.get("runAsNonRoot") or pod_sc.get("runAsNonRoot")
        ):
            yield f"{name}: runAsNonRoot is not true"
        if sc.get("runAsUser") == 0:
            yield f"{name}: runAsUser: 0"
        # "Seccomp": RuntimeDefault or Localhost, on the pod or on every container
        profile = _seccomp(sc) or _seccomp(pod_sc)
        if profile not in SECCOMP_OK:
            yield f"{name}: seccompProfile {profile!r}"
        caps = sc.get("capabilities") or {}  # "Capabilities"
        if "ALL" not in (caps.get("drop") or ()):
            yield f"{name}: capabilities do not drop ALL"
        extra = set(caps.get("add") or ()) - RESTRICTED_ADDS
        if extra:
            yield f"{name}: capabilities add {sorted(extra)}"


def violations(pod_spec: Obj) -> list[str]:
    """Every way ``pod_spec`` breaks the restricted profile (empty: admitted)."""
    return [*_baseline(pod_spec), *_restricted(pod_spec)]
