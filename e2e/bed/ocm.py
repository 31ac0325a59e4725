"""Open Cluster Management on the bed (issue 47; MULTICLUSTER.md 1.4): the cloud cluster is the
hub, and its managed clusters are the bed's own cluster (``site``) and the cloud cluster itself
(``cloud``, as OCM's "self-managed hub").

- **The hub**: OCM's hub CRDs on the cloud cluster, and its registration controller
  (``registration controller``) run as the cloud's admin.
- **An agent per managed cluster**: OCM's singleton klusterlet agent (``registration-operator
  agent``: registration and work in one process), with the managed cluster's CRDs
  (ClusterClaims, AppliedManifestWorks) installed there. The site's reaches the hub across
  the WAN (``cloud.WAN``), as a site's agent dials out to a cloud hub. Each starts from a
  bootstrap kubeconfig of a hub ServiceAccount bound to OCM's own bootstrap ClusterRole, which
  may create certificate requests and ManagedClusters and nothing else, and keeps its hub
  credentials in a directory of its own.
- **The join**, as ``clusteradm accept`` does it: the bed approves the agent's first
  certificate request and sets ``hubAcceptsClient`` on its ManagedCluster; the agent then gets
  its certificate, and OCM's own conditions say the cluster is Joined and Available.

The OCM processes listen on 127.0.0.1 only (``--listen``), and run without leader election
(one of each).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import yaml

from e2e.bed.base import BIN_DIR, HOST, REPO_ROOT, TOOLS_DIR, HarnessError, free_port, log, wait_for
from e2e.bed.base import kubectl as run_kubectl
from e2e.bed.cloud import CLOUD_DIR, CloudCluster
from e2e.bed.cluster import condition_status
from e2e.bed.gomodule import GoToolchain
from e2e.bed.processes import _alive, _start, _stop, log_tail


class _ToolDir(Protocol):
    """What ``build`` needs of ``tools.Tool`` (named so, not imported: tools imports this)."""

    root: Path


__all__ = [
    "AGENT_NAMESPACE",
    "CLUSTERS",
    "COMMANDS",
    "HUB",
    "MANIFESTS",
    "PROCESSES",
    "Joined",
    "build",
    "join",
    "stop",
]

# OCM's hub registration controller and its singleton klusterlet agent (registration + work).
COMMANDS = ("registration", "registration-operator")
OCM_MODULE = "open-cluster-management.io/ocm"
# What the bed installs of OCM's own manifests (read from the module cache, not copied into
# the repository): the hub's CRDs, the managed cluster's, and the bootstrap ClusterRole.
MANIFESTS = {
    "hub-crds": "manifests/cluster-manager/hub",
    "managed-crds": "manifests/klusterlet/managed",
}
BOOTSTRAP_ROLE_FILE = (
    "deploy/cluster-manager/chart/cluster-manager/templates/bootstrap_cluster_role.yaml"
)

HUB = "ocm-hub"
CLUSTERS = ("site", "cloud")  # the ManagedClusters: the bed's cluster, the cloud cluster
AGENT_NAMESPACE = "open-cluster-management-agent"
HUB_SECRET = "hub-kubeconfig-secret"  # the agent's hub credentials, on its managed cluster
BOOTSTRAP_NAMESPACE = "open-cluster-management"
BOOTSTRAP_SA = "agent-registration-bootstrap"
BOOTSTRAP_ROLE = "open-cluster-management:bootstrap"
JOIN_TIMEOUT_S = 120
HUB_RBAC = REPO_ROOT / "manifests" / "ocm-hub" / "rbac.yaml"  # what a site's operator may do there
SITE_ACCOUNT = ("fogfleet-hub", "fogfleet-site")  # its ServiceAccount there
HUB_KEEPER = REPO_ROOT / "manifests" / "ocm-hub" / "keeper.yaml"  # the hub keeper, on the hub
KEEPER_ACCOUNT = ("fogfleet-hub", "fogfleet-hub-keeper")
# how often an agent renews its ManagedCluster's Lease; the hub calls a cluster unavailable
# after 5 of them unrenewed (OCM's rule), so 10 s here: 50 s
LEASE_SECONDS = 10


def agent_name(cluster: str) -> str:
    return f"ocm-agent-{cluster}"


PROCESSES = (HUB, *(agent_name(c) for c in CLUSTERS))


def _hub_dir(cluster: str) -> Path:
    """Where the agent of ``cluster`` keeps its hub credentials (its kubeconfig, key, cert)."""
    return CLOUD_DIR / "ocm" / cluster


def _manifests(v_ocm: str) -> Path:
    return TOOLS_DIR / f"ocm-{v_ocm}" / "manifests"


@dataclass(frozen=True)
class Joined:
    """The managed clusters as the hub sees them once joined, and how long the join took."""

    clusters: tuple[str, ...]
    seconds: float  # from OCM's install (CRDs, then the hub and agents) until all are Available


def _kubectl(kubeconfig: Path, *args: str, input: str | None = None) -> str:
    return run_kubectl(BIN_DIR / "kubectl", kubeconfig, *args, input=input).stdout


def _apply_crds(kubeconfig: Path, folder: Path) -> None:
    _kubectl(kubeconfig, "apply", "--server-side", "-f", str(folder))
    _kubectl(kubeconfig, "wait", "--for=condition=Established", "--timeout=60s", "crd", "--all")


def _bootstrap_kubeconfigs(cloud: CloudCluster, manifests: Path) -> dict[str, Path]:
    """Per managed cluster, a kubeconfig of the hub's bootstrap ServiceAccount (OCM's
    bootstrap ClusterRole) with a token that outlives the bed: the site's names the hub across
    the WAN (``cloud.from_site``), the cloud's names it directly. The hub kubeconfig an agent
    gets keeps its bootstrap's server."""
    kc = cloud.kubeconfig
    _kubectl(kc, "apply", "-f", str(manifests / "bootstrap"))
    objects = {
        "apiVersion": "v1",
        "kind": "List",
        "items": [
            {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": BOOTSTRAP_NAMESPACE}},
            {
                "apiVersion": "v1",
                "kind": "ServiceAccount",
                "metadata": {"name": BOOTSTRAP_SA, "namespace": BOOTSTRAP_NAMESPACE},
            },
            {
                "apiVersion": "rbac.authorization.k8s.io/v1",
                "kind": "ClusterRoleBinding",
                "metadata": {"name": f"{BOOTSTRAP_ROLE}:agent-registration"},
                "roleRef": {
                    "apiGroup": "rbac.authorization.k8s.io",
                    "kind": "ClusterRole",
                    "name": BOOTSTRAP_ROLE,
                },
                "subjects": [
                    {
                        "kind": "ServiceAccount",
                        "name": BOOTSTRAP_SA,
                        "namespace": BOOTSTRAP_NAMESPACE,
                    }
                ],
            },
        ],
    }
    _kubectl(kc, "apply", "-f", "-", input=json.dumps(objects))
    token = _kubectl(
        kc, "create", "token", BOOTSTRAP_SA, "-n", BOOTSTRAP_NAMESPACE, "--duration=24h"
    ).strip()
    return {
        cluster: _token_kubeconfig(cloud, BOOTSTRAP_SA, token, server, f"bootstrap-{cluster}")
        for cluster, server in (("site", cloud.from_site), ("cloud", cloud.api_server))
    }


def _token_kubeconfig(cloud: CloudCluster, user: str, token: str, server: str, name: str) -> Path:
    """A kubeconfig of the hub as ``user`` with ``token``, naming it at ``server``."""
    cfg = json.loads(cloud.kubeconfig.read_text())
    cfg["users"] = [{"name": user, "user": {"token": token}}]
    cfg["contexts"][0]["context"]["user"] = user
    cfg["clusters"][0]["cluster"]["server"] = server
    path = CLOUD_DIR / "ocm" / f"{name}.kubeconfig"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cfg, indent=1) + "\n")
    path.chmod(0o600)
    return path


def _account_kubeconfig(
    cloud: CloudCluster, documents: Sequence[Mapping[str, object]], account: tuple[str, str],
    server: str, name: str,
) -> Path:  # fmt: skip
    """Apply ``documents`` on the hub, and a kubeconfig of its ServiceAccount ``account``
    (namespace, name) naming the hub at ``server``."""
    items = {"apiVersion": "v1", "kind": "List", "items": list(documents)}
    _kubectl(cloud.kubeconfig, "apply", "-f", "-", input=json.dumps(items))
    namespace, sa = account
    token = _kubectl(
        cloud.kubeconfig, "create", "token", sa, "-n", namespace, "--duration=24h"
    ).strip()
    return _token_kubeconfig(cloud, sa, token, server, name)


def _documents(path: Path) -> list[dict[str, object]]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def site_operator_kubeconfig(cloud: CloudCluster) -> Path:
    """The hub kubeconfig the site's fogfleet operator gets (FOGFLEET_HUB_KUBECONFIG): the
    ServiceAccount of ``manifests/ocm-hub/rbac.yaml``, applied as a user applies it, naming
    the hub across the WAN. It reads ManagedClusters and writes ManifestWorks in the cloud's
    namespace, and nothing else."""
    return _account_kubeconfig(
        cloud, _documents(HUB_RBAC), SITE_ACCOUNT, cloud.from_site, "site-operator"
    )


def keeper_kubeconfig(cloud: CloudCluster) -> Path:
    """The hub keeper's kubeconfig: the ServiceAccount and rights of
    ``manifests/ocm-hub/keeper.yaml`` (its Deployment is left out: the bed runs the keeper as a
    process beside the hub, as it runs OCM's own), naming the hub directly."""
    namespace = [d for d in _documents(HUB_RBAC) if d["kind"] == "Namespace"]
    rights = namespace + [d for d in _documents(HUB_KEEPER) if d["kind"] != "Deployment"]
    return _account_kubeconfig(cloud, rights, KEEPER_ACCOUNT, cloud.api_server, "hub-keeper")


def _argv(
    cloud: CloudCluster,
    managed: Mapping[str, Path],
    bootstrap: Mapping[str, Path],
    ports: Mapping[str, int],
) -> dict[str, list[str]]:
    argv = {
        HUB: [
            str(BIN_DIR / "registration"),
            "controller",
            f"--kubeconfig={cloud.kubeconfig}",
            f"--listen={HOST}:{ports[HUB]}",
            "--disable-leader-election",
            f"--namespace={BOOTSTRAP_NAMESPACE}",
        ]
    }
    for cluster, kubeconfig in managed.items():
        name = agent_name(cluster)
        argv[name] = [
            str(BIN_DIR / "registration-operator"),
            "agent",
            f"--cluster-name={cluster}",
            f"--agent-id={cluster}-agent",
            f"--kubeconfig={kubeconfig}",
            f"--spoke-kubeconfig={kubeconfig}",
            f"--bootstrap-kubeconfig={bootstrap[cluster]}",
            f"--hub-kubeconfig-dir={_hub_dir(cluster)}",
            f"--hub-kubeconfig-secret={HUB_SECRET}",
            # the work agent reads the hub kubeconfig the registration agent writes there
            f"--workload-source-config={_hub_dir(cluster) / 'kubeconfig'}",
            f"--namespace={AGENT_NAMESPACE}",
            f"--listen={HOST}:{ports[name]}",
            "--disable-leader-election",
        ]
    return argv


def _accept(cloud: CloudCluster, clusters: Sequence[str]) -> set[str]:
    """One pass of ``clusteradm accept``: approve the pending certificate requests of
    ``clusters`` and accept their ManagedClusters; return the clusters now Available."""
    kc = cloud.kubeconfig
    csrs = json.loads(_kubectl(kc, "get", "csr", "-o", "json"))["items"]
    for csr in csrs:
        labels = csr["metadata"].get("labels", {})
        pending = not (csr.get("status") or {}).get("conditions")
        if pending and labels.get("open-cluster-management.io/cluster-name") in clusters:
            _kubectl(kc, "certificate", "approve", csr["metadata"]["name"])
    available = set()
    for mc in json.loads(_kubectl(kc, "get", "managedclusters", "-o", "json"))["items"]:
        name = mc["metadata"]["name"]
        if name not in clusters:
            continue
        if not mc["spec"].get("hubAcceptsClient"):
            patch = {"spec": {"hubAcceptsClient": True, "leaseDurationSeconds": LEASE_SECONDS}}
            _kubectl(kc, "patch", "managedcluster", name, "--type=merge", "-p", json.dumps(patch))
        if condition_status(mc, "ManagedClusterConditionAvailable") == "True":
            available.add(name)
    return available


def join(cloud: CloudCluster, site_kubeconfig: Path, ocm_version: str) -> Joined:
    """Install OCM's hub on ``cloud``, an agent for the site and one for the cloud, and accept
    both; returns once the hub says both are Available."""
    manifests = _manifests(ocm_version)
    managed = {"site": site_kubeconfig, "cloud": cloud.kubeconfig}
    t0 = time.monotonic()
    _apply_crds(cloud.kubeconfig, manifests / "hub-crds")
    for kubeconfig in managed.values():
        _apply_crds(kubeconfig, manifests / "managed-crds")
        _kubectl(
            kubeconfig, "apply", "-f", "-",
            input=json.dumps({"apiVersion": "v1", "kind": "Namespace",
                              "metadata": {"name": AGENT_NAMESPACE}}),
        )  # fmt: skip
    names = list(PROCESSES)
    if all(_alive(n) for n in names) and _accept(cloud, CLUSTERS) >= set(CLUSTERS):
        log(f"ocm: {', '.join(CLUSTERS)} already joined and Available")
        return Joined(CLUSTERS, 0.0)
    stop()
    for cluster, kubeconfig in managed.items():  # what an earlier hub gave it, as unjoin does
        _kubectl(kubeconfig, "delete", "secret", HUB_SECRET, "-n", AGENT_NAMESPACE,
                 "--ignore-not-found")  # fmt: skip
        shutil.rmtree(_hub_dir(cluster), ignore_errors=True)
    bootstrap = _bootstrap_kubeconfigs(cloud, manifests)
    ports = {name: free_port() for name in names}
    argv = _argv(cloud, managed, bootstrap, ports)
    for name in names:
        _start(name, argv[name])
    available: set[str] = set()

    def all_available() -> bool:
        dead = [n for n in names if _alive(n) is None]
        if dead:
            raise _Exited(dead)
        available.update(_accept(cloud, CLUSTERS))
        return available >= set(CLUSTERS)

    try:
        wait_for("the site and cloud clusters Available on the OCM hub", all_available,
                 JOIN_TIMEOUT_S, 1.0, fatal=(_Exited,))  # fmt: skip
    except HarnessError as exc:
        tails = "\n".join(f"--- {n}:\n{log_tail(n, 15)}" for n in names)
        stop()  # the next join starts them again from their bootstrap
        raise HarnessError(f"{exc} (available: {sorted(available) or 'none'})\n{tails}") from exc
    seconds = time.monotonic() - t0
    log(f"ocm: {', '.join(CLUSTERS)} joined and Available in {seconds:.1f}s")
    return Joined(CLUSTERS, seconds)


def build(tool: _ToolDir, v: Mapping[str, str], go: GoToolchain, blog: Path) -> None:
    """OCM's ``registration`` and ``registration-operator`` commands, in a module of their own:
    OCM v1.0.0 is built against the Kubernetes libraries v0.32, the bed's module against v0.36.
    Its ``go.sum`` is seeded from OCM's own (the checksum database answers 404 here for one of
    OCM's dependencies, ``sigs.k8s.io/about-api``; OCM's go.sum records its hash, so every
    module stays verified). Then OCM's manifests the bed installs are copied out of the module
    cache into the tool's directory."""
    ov = v["OCM_VERSION"]
    src = tool.root / "module"
    if not (src / "resolved").exists():
        shutil.rmtree(src, ignore_errors=True)
        src.mkdir(parents=True)
        go("mod", "init", "e2e.local/bedocm", cwd=src, log_file=blog)
        go("mod", "edit", f"-go={v['GO_MIN_VERSION']}", cwd=src, log_file=blog)
        upstream = Path(go.download(f"{OCM_MODULE}@v{ov}", src)["Dir"])
        (src / "go.sum").write_text((upstream / "go.sum").read_text())
        packages = [f"{OCM_MODULE}/cmd/{c}@v{ov}" for c in COMMANDS]
        go("get", "-tool", *packages, cwd=src, log_file=blog)
        (src / "resolved").write_text("\n".join(packages) + "\n")
    (tool.root / "bin").mkdir(parents=True, exist_ok=True)
    go(
        "build", "-v", "-trimpath",
        "-ldflags", f"-s -w -X {OCM_MODULE}/pkg/version.versionFromGit=v{ov}",
        "-o", str(tool.root / "bin"), *(f"{OCM_MODULE}/cmd/{c}" for c in COMMANDS),
        cwd=src, log_file=blog,
    )  # fmt: skip
    upstream = Path(go.download(f"{OCM_MODULE}@v{ov}", src)["Dir"])
    out = tool.root / "manifests"
    shutil.rmtree(out, ignore_errors=True)
    for name, folder in MANIFESTS.items():
        (out / name).mkdir(parents=True)
        for crd in sorted((upstream / folder).glob("*.crd.yaml")):
            (out / name / crd.name).write_text(crd.read_text())
    # a Helm template with one `if`: the ClusterRole inside it is plain YAML
    role = (upstream / BOOTSTRAP_ROLE_FILE).read_text()
    (out / "bootstrap").write_text("\n".join(ln for ln in role.splitlines() if "{{" not in ln))


class _Exited(HarnessError):
    def __init__(self, names: list[str]) -> None:
        super().__init__(f"{', '.join(names)} exited")


def stop() -> None:
    """Stop the agents, then the hub (by pid)."""
    for cluster in CLUSTERS:
        _stop(agent_name(cluster))
    _stop(HUB)
