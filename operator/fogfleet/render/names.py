"""The name of every object fogfleet renders: its own across all fleets of a namespace, and
one its kind takes (issue 45 item 4).

Fleet, robot and module names may contain ``-``, so a plain ``-`` join is not a name of its
own: fleet ``a-b`` robot ``c`` and fleet ``a`` robot ``b-c`` both join to ``a-b-c``, and two
fleets of one namespace would share a discovery server and a robot NetworkPolicy. The rule,
:func:`object_name`, keeps the plain join where it can be read one way only, and otherwise
adds a hash of the exact tuple, as Kubernetes itself names what it generates (a ReplicaSet is
``<deployment>-<pod-template-hash>``, a generated name a readable base plus a suffix):

* **plain** ``<part>-...-<part>-<role>`` when every part but the last is one word (no ``-``),
  every part is already a DNS label (no dot, no upper case), and the result fits its kind.
  The role word (``dds``, ``net``, ``pods``...) is fixed per object, so the parts are read
  back by splitting at the first dashes: two plain names of one kind never meet. The common
  case keeps the names users and the docs know: ``warehouse-robot-1-dds``,
  ``warehouse-pods``, ``warehouse-robot-1-net``.
* **hashed** ``<the join, cut to fit>-<role>-<hash8>`` otherwise, where ``hash8`` is the
  sha256 of the exact tuple (``api.names.digest``): a join that two tuples share, a name the
  cleaning changed, one too long, or (a Service) one that begins with a digit, which then
  begins with its role word instead (``dds-42-warehouse-robot-1-<hash8>``). Hashed names end
  in eight hex digits and plain ones in a role word, so the two forms never meet either; two
  hashed names meet only if their tuples' hashes do (32 bits) and their readable heads too.

A module's Deployment is always hashed (``<fleet>-<robot>-<module>-<hash8>``, a shared replica
``<fleet>-<module>-r<k>-<hash8>``, a standby with ``-standby`` before the hash), as it was
before this rule: names that stay the same leave running modules alone on an upgrade.

The kinds (:class:`Kind`): a Service name is a DNS-1035 label (a letter first, 63 at most);
every other name is kept a DNS-1123 label of 63 at most, so it is also a valid label value
(``fogfleet.io/instance`` carries a Deployment's name). A Deployment's name is at most 57:
Kubernetes names its pods ``<deployment>-<pod-template-hash>-<5 random>`` after cutting the
part before the random one to 58 characters, so up to 57 every pod's name begins with
``<deployment>-`` and :func:`pod_deployment` finds its Deployment (the drift pass counts a
fleet's pods in Prometheus by it). A discovery server's Service and Deployment share one name,
under both rules.

The profiling Job of a module is the module's, not a fleet's (a SoftwareModule's name is its
own in the namespace): :func:`profiling_job_name` keeps its name as before.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Collection
from dataclasses import dataclass

from fogfleet.api.labels import ROLE_STANDBY
from fogfleet.api.names import digest, dns_label, dns_text
from fogfleet.domain.problem import Instance

__all__ = [
    "DEPLOYMENT",
    "LABELLED",
    "SERVICE",
    "Kind",
    "container_name",
    "deployment_name",
    "discovery_service_name",
    "hpa_name",
    "metrics_network_policy_name",
    "network_policy_name",
    "object_name",
    "pod_deployment",
    "profiling_job_name",
    "relay_name",
    "relay_network_policy_name",
    "robot_network_policy_name",
    "scaled_object_name",
    "shared_network_policy_name",
    "work_name",
]


@dataclass(frozen=True)
class Kind:
    """What a kind takes as a name: at most ``limit`` characters of a DNS-1123 label, and with
    ``letter_first`` a DNS-1035 label (a letter first)."""

    limit: int
    letter_first: bool = False

    def takes(self, name: str) -> bool:
        return (
            len(name) <= self.limit
            and _DNS_LABEL.fullmatch(name) is not None
            and (not self.letter_first or name[0].isalpha())
        )


SERVICE = Kind(63, letter_first=True)
DEPLOYMENT = Kind(57)
"""Its pods' names begin with it and a dash: 58 (SimpleNameGenerator's base) - 1."""
LABELLED = Kind(63)
"""NetworkPolicy, HPA, ScaledObject, a container: a DNS-1123 label, also a label value."""
_DISCOVERY = Kind(min(SERVICE.limit, DEPLOYMENT.limit), letter_first=True)

_WORD = re.compile(r"[a-z0-9]+")
_DNS_LABEL = re.compile(r"[a-z0-9]([-a-z0-9]*[a-z0-9])?")


def object_name(role: str, *parts: str, kind: Kind = LABELLED) -> str:
    """``<parts>-<role>`` where that is read one way only and ``kind`` takes it, else the
    hashed form (the module docstring)."""
    plain = "-".join((*parts, role))
    *words, last = parts
    one_reading = all(_WORD.fullmatch(w) for w in words) and _DNS_LABEL.fullmatch(last)
    if one_reading and kind.takes(plain):
        return plain
    return _hashed(parts, role, (role, *parts), kind)


def _hashed(parts: tuple[str, ...], role: str, identity: tuple[object, ...], kind: Kind) -> str:
    """``<the parts' join, cut>[-<role>]-<hash8 of identity>``, within ``kind.limit``; a name
    that must begin with a letter and would not begins with its role word."""
    tag = digest(*identity)
    text = dns_text("-".join(p for p in parts if p))
    if kind.letter_first and not text[:1].isalpha():
        first, last = f"{role}-", f"-{tag}"
    else:
        first, last = "", f"-{role}-{tag}" if role else f"-{tag}"
    head = text[: kind.limit - len(first) - len(last)].strip("-")
    return f"{first}{head}{last}" if head else f"{first}{last[1:]}"


# ---------------------------------------------------------------------- a fleet's objects
def deployment_name(fleet: str, inst: Instance, role: str = "") -> str:
    """A module instance's Deployment: ``<fleet>-<robot>-<module>-<hash8>`` (a shared replica
    ``<fleet>-<module>-r<k>-<hash8>``; an on-board standby ``...-<module>-standby-<hash8>``),
    always hashed, of at most 57 characters."""
    parts = (
        (fleet, inst.robot, inst.module) if inst.robot else (fleet, inst.module, f"r{inst.replica}")
    )
    identity: tuple[object, ...] = (fleet, inst.robot, inst.module, inst.replica)
    standby = role == ROLE_STANDBY
    if standby:
        identity += (ROLE_STANDBY,)
    return _hashed(parts, ROLE_STANDBY if standby else "", identity, DEPLOYMENT)


def work_name(site: str, namespace: str, deployment: str) -> str:
    """The ManifestWork that runs a module's Deployment in a managed cluster, in the hub's
    namespace of that cluster (render.manifestwork): ``<namespace>-<deployment>-<hash8>``,
    hashed with the site so that several sites' works of one namespace never meet."""
    return _hashed((namespace, deployment), "", (site, namespace, deployment), LABELLED)


def discovery_service_name(fleet: str, robot: str) -> str:
    """``<fleet>-<robot>-dds``: the Service and the Deployment of the robot's discovery
    server (a DNS-1035 label of at most 57 characters)."""
    return object_name("dds", fleet, robot, kind=_DISCOVERY)


def relay_name(fleet: str, robot: str) -> str:
    """``<fleet>-<robot>-relay``: the Deployment of the robot's relay to the managed clusters
    (render.relays), of at most 57 characters."""
    return object_name("relay", fleet, robot, kind=DEPLOYMENT)


def relay_network_policy_name(fleet: str) -> str:
    """``<fleet>-relay``, the NetworkPolicy that lets the fleet's relays dial the site's router."""
    return object_name("relay", fleet)


def network_policy_name(fleet: str) -> str:
    """``<fleet>-pods``, the NetworkPolicy of every pod of the fleet."""
    return object_name("pods", fleet)


def shared_network_policy_name(fleet: str) -> str:
    """``<fleet>-shared``, the NetworkPolicy of the fleet's shared services."""
    return object_name("shared", fleet)


def metrics_network_policy_name(fleet: str) -> str:
    """``<fleet>-metrics``, the NetworkPolicy opening the metrics ports to Prometheus."""
    return object_name("metrics", fleet)


def robot_network_policy_name(fleet: str, robot: str) -> str:
    """``<fleet>-<robot>-net``, the NetworkPolicy of one robot's pods."""
    return object_name("net", fleet, robot)


def hpa_name(fleet: str, module: str) -> str:
    """``<fleet>-<module>-hpa``, the HPA of the fleet's replica of a shared module."""
    return object_name("hpa", fleet, module)


def scaled_object_name(fleet: str, module: str) -> str:
    """``<fleet>-<module>-scaler``, the KEDA ScaledObject of the fleet's replica of a shared
    module."""
    return object_name("scaler", fleet, module)


def container_name(module: str) -> str:
    """The module's container: its name in DNS-label characters (a dotted name with ``-``),
    hashed only when longer than 63; one container per pod, so it needs no more."""
    return dns_label(dns_text(module)) or "module"


def pod_deployment(pod: str, deployments: Collection[str]) -> str | None:
    """Which of ``deployments`` the pod named ``pod`` belongs to, if any: the longest whose
    name and a dash begin the pod's (every pod's name does, its Deployment's name being at most
    57 characters). Another Deployment's pod could pass only with a name that begins with one
    of ``deployments`` and a dash: a module's Deployment name ends in its own hash."""
    ends = [k for k, char in enumerate(pod) if char == "-"]
    return next((pod[:k] for k in reversed(ends) if pod[:k] in deployments), None)


# ------------------------------------------------------------------------ a module's objects
def profiling_job_name(module: str, hardware_type: str, cpu: float, spec_hash: str) -> str:
    """``<module>-profile-<digest>``, at most 49 characters (a Job's pods append their own
    suffix to it and must stay a valid label value); a module name over 32 characters is cut
    with a hash of it (``api.names``), so two long modules never share a Job."""
    run = hashlib.sha256(f"{hardware_type}/{cpu:g}/{spec_hash}".encode()).hexdigest()[:8]
    head = dns_label(dns_text(module), limit=32)
    return f"{head}-profile-{run}"
