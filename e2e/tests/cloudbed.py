"""The cloud cluster beside the bed, as the multicluster tests use it (issue 47): joined by
OCM, the site's operator placing into it, a fleet with a module too large for the robot.

Shared by ``test_multicluster`` (OCM, placement, the keeper) and ``test_multicluster_ros`` (ROS
2 across the WAN); each module joins the cloud afresh (``joined_cloud``) and stops it after.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from e2e.bed import cloud, ocm
from e2e.bed.base import free_port
from e2e.bed.bed import ensure_cloud
from e2e.bed.cluster import condition_status
from e2e.bed.harness import Cluster
from e2e.bed.kube import Kube
from e2e.bed.operator_fixtures import Operator, example_in, wait_ready
from fogfleet.api.labels import LABEL_MODULE
from fogfleet.contract.env import ENV_METRICS_HOST, ENV_METRICS_PORT
from fogfleet.snapshot.clusters import ROUTER_CLAIM


@contextlib.contextmanager
def joined_cloud(
    cluster: Cluster, *, real_node: bool = False
) -> Iterator[tuple[cloud.CloudCluster, ocm.Joined]]:
    """The cloud joined to the site ``cluster`` (a cloud left by an earlier session is
    started again, so that the join is measured), with its real node if ``real_node``;
    stopped after."""
    ocm.stop()
    cloud.stop()
    try:
        yield ensure_cloud(cluster, real_node=real_node)
    finally:
        ocm.stop()
        cloud.stop()


def site_available(hub: cloud.CloudCluster) -> str | None:
    """The site's ManagedClusterConditionAvailable, as the hub says it."""
    mc = json.loads(hub.kubectl("get", "managedcluster", "site", "-o", "json"))
    return condition_status(mc, "ManagedClusterConditionAvailable")


ROBOT = "bed-robot-1"  # the bed's real robot node every multicluster fleet has
CLOUD_NODE = "e2e-cloud"  # the ComputeNode that stands for the cloud cluster
CLAIMS = {  # what the cloud says of itself (ClusterClaims on it, reported to the hub)
    "privacy-level.fogfleet.io": "1",
    "cost-per-core-hour.fogfleet.io": "0.05",
    "wan-latency-millis.fogfleet.io": "20",
    "wan-bandwidth-mbps.fogfleet.io": "50",
}
SITE_NAME = "site"  # the site's ManagedCluster name: what the operator labels its works with
POSE_CYCLE_MS = 200  # the localisation's: five poses a second cross to the mapping
MODULE_DEFAULTS = {
    "template": {"image": "ghcr.io/fogfleet/ros2-module:0.1.0", "imagePullPolicy": "Never"},
    "cycleTimeMillis": 1000,
    "activationPercent": 100,
}


def module(namespace: str, name: str, **spec: Any) -> dict[str, Any]:
    return {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "SoftwareModule",
        "metadata": {"name": name, "namespace": namespace},
        "spec": {**MODULE_DEFAULTS, **spec},
    }


def robot_and_cloud(namespace: str) -> list[dict[str, Any]]:
    """The ComputeNodes of the bed's robot (``ROBOT``) and of the cloud cluster."""
    robot = next(
        d for d in example_in("warehouse-lite", namespace) if d["metadata"]["name"] == ROBOT
    )
    robot["metadata"].pop("labels", None)
    cloud_node = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "ComputeNode",
        "metadata": {"name": CLOUD_NODE},
        # privacy, price and WAN link: the cloud's own ClusterClaims (CLAIMS)
        "spec": {"tier": "cloud", "hardwareType": "cloud-vm", "managedCluster": "cloud"},
    }
    return [robot, cloud_node]


def cloud_fleet(namespace: str) -> list[dict[str, Any]]:
    """One bed robot and the cloud cluster as a ComputeNode; a mapping module too large for
    the robot (2 cores) whose data needs privacy 1, which only the cloud's claim grants (a
    cloud's default is 0), a localisation that reads the robot's lidar and publishes its pose
    (the one cut edge: mapping subscribes to it), and a recorder whose data may not leave the
    robot (minPrivacy 2), which publishes a recording that nothing in the cloud hears."""
    light = {"executionPattern": "periodic", "realtime": "none", "safety": "irrelevant"}
    modules = [
        module(
            namespace, "localization",
            taxonomy={"executionPattern": "continuous", "realtime": "soft", "safety": "relevant"},
            resources={"cpu": "20m", "memory": "128Mi"},
            requirements={"devices": ["lidar"]},
            profile=[{"hardwareType": "default", "cpu": "50m", "meanMillis": 20, "stdMillis": 2}],
            cycleTimeMillis=POSE_CYCLE_MS,
            topics={"publishes": [{"name": "pose", "sizeBytes": "1Ki", "rateHz": 5}]},
        ),
        module(
            namespace, "mapping",
            taxonomy=light,
            resources={"cpu": "2", "memory": "256Mi"},
            requirements={"minPrivacy": 1},
            profile=[{"hardwareType": "default", "cpu": "2", "meanMillis": 300, "stdMillis": 20}],
            topics={"subscribes": [{"name": "pose", "sizeBytes": "1Ki", "rateHz": 1}]},
        ),
        module(
            namespace, "private-recorder",
            taxonomy=light,
            resources={"cpu": "10m", "memory": "64Mi"},
            requirements={"minPrivacy": 2},
            profile=[{"hardwareType": "default", "cpu": "20m", "meanMillis": 50, "stdMillis": 5}],
            topics={"subscribes": [{"name": "pose", "sizeBytes": "1Ki", "rateHz": 1}],
                    "publishes": [{"name": "recording", "sizeBytes": "1Ki", "rateHz": 1}]},
        ),
    ]  # fmt: skip
    fleet = {
        "apiVersion": "fogfleet.io/v1alpha1",
        "kind": "RobotFleet",
        "metadata": {"name": "mapped", "namespace": namespace},
        "spec": {
            "robots": ["bed-robot-1"],
            "nodes": [CLOUD_NODE],
            "modules": [{"name": m["metadata"]["name"]} for m in modules],
            "scheduler": {"algorithm": "nsga2", "seed": 1},
        },
    }
    return [*robot_and_cloud(namespace), *modules, fleet]


def works_of(hub: cloud.CloudCluster, namespace: str) -> list[dict[str, Any]]:
    """The works the site's operator wrote on the hub for ``namespace``, in every cluster."""
    selector = f"fogfleet.io/site={SITE_NAME},fogfleet.io/namespace={namespace}"
    found = hub.kubectl("get", "manifestworks", "-A", "-o", "json", "-l", selector)
    items: list[dict[str, Any]] = json.loads(found)["items"]
    return items


def cloud_pods(hub: cloud.CloudCluster, namespace: str) -> list[dict[str, Any]]:
    found = hub.kubectl("get", "pods", "-n", namespace, "-o", "json", check=False)
    return json.loads(found)["items"] if found else []


def claim_the_cloud(hub: cloud.CloudCluster, kube: Kube, router: str | None = None) -> None:
    """The cloud's ClusterClaims (``CLAIMS``, and the router its pods' relays dial: the
    host's loopback one by default, for pods played on the host; ``hub.cloud_router_for_pods``
    for pods in the cloud's real node), once the hub reports them."""
    said = {**CLAIMS, ROUTER_CLAIM: router or hub.cloud_router}
    claims = [
        {"apiVersion": "cluster.open-cluster-management.io/v1alpha1", "kind": "ClusterClaim",
         "metadata": {"name": name}, "spec": {"value": value}}
        for name, value in said.items()
    ]  # fmt: skip
    hub.kubectl("apply", "-f", "-", input=json.dumps({"apiVersion": "v1", "kind": "List",
                                                      "items": claims}))  # fmt: skip

    def reported() -> dict[str, str]:
        mc = json.loads(hub.kubectl("get", "managedcluster", "cloud", "-o", "json"))
        return {c["name"]: c["value"] for c in mc["status"].get("clusterClaims", [])}

    kube.wait_for("the cloud's claims on the hub", lambda: reported().items() >= said.items())


def run_in_the_cloud(hub: cloud.CloudCluster, kube: Kube, namespace: str) -> float:
    """The cloud claimed, then ``cloud_fleet`` applied and Ready: how long from the apply."""
    claim_the_cloud(hub, kube)
    applied = time.monotonic()
    kube.apply(cloud_fleet(namespace))
    wait_ready(kube, namespace, "mapped", timeout=240)
    return time.monotonic() - applied


@contextlib.contextmanager
def site_operator(
    hub: cloud.CloudCluster, kube: Kube, namespace: str, tmp_path: Path, diagnostics: list[Any]
) -> Iterator[Operator]:
    """``fogfleet run`` at the site with the hub's kubeconfig of ``manifests/ocm-hub`` (across
    the WAN) and none of the cloud cluster's."""
    env = {
        "FOGFLEET_HUB_KUBECONFIG": str(ocm.site_operator_kubeconfig(hub)),
        "FOGFLEET_CLUSTER_NAME": SITE_NAME,
        "FOGFLEET_SITE_ROUTER": hub.site_router_for_pods,
    }
    op = Operator(kube.kubeconfig, [namespace], tmp_path / "operator.log", env)
    diagnostics.append(lambda: ("operator log", op.logs(150)))
    op.start().wait_live()
    yield op
    kube.kubectl("delete", "robotfleets", "--all", "-n", namespace, "--wait=true",
                 "--timeout=60s", check=False, timeout=90)  # fmt: skip
    kube.kubectl("delete", "computenode", CLOUD_NODE, "--ignore-not-found", check=False)
    op.stop()


@contextlib.contextmanager
def only_the_real_node(hub: cloud.CloudCluster) -> Iterator[None]:
    """The cloud's kwok machines cordoned, so that its scheduler binds new pods to its real
    node (``cloud.NODE``); uncordoned after."""
    hub.kubectl("cordon", *cloud.NODES)
    try:
        yield
    finally:
        hub.kubectl("uncordon", *cloud.NODES, check=False)


def real_node_logs(namespace: str) -> str:
    """The last lines of every container log of ``namespace``'s pods on the cloud's real
    node (read from the node's log directory: the cloud's API server holds no kubelet client
    certificate, so ``kubectl logs`` cannot reach it)."""
    found = sorted((cloud.NODE.dir / "pod-logs").glob(f"{namespace}_*/*/*.log"))
    return "\n".join(f"{p.parent.name}: {p.read_text(errors='replace')[-1500:]}" for p in found)


def work_deployment(hub: cloud.CloudCluster, namespace: str, module: str) -> dict[str, Any]:
    """The Deployment that ``module``'s one work in ``namespace`` carries to the cloud."""
    found = [
        m
        for w in works_of(hub, namespace)
        for m in w["spec"]["workload"]["manifests"]
        if m["kind"] == "Deployment" and m["metadata"]["labels"].get(LABEL_MODULE) == module
    ]
    assert len(found) == 1, [m["metadata"]["name"] for m in found]
    return found[0]


def container_env(deployment: dict[str, Any], container: str) -> dict[str, str]:
    """A container's environment (its plain values) in ``deployment``."""
    containers = deployment["spec"]["template"]["spec"]["containers"]
    (found,) = [c for c in containers if c["name"] == container]
    return {e["name"]: e["value"] for e in found.get("env", []) if "value" in e}


@contextlib.contextmanager
def cloud_pod_on_the_host(
    deployment: dict[str, Any], domain: int, logs: Path, only: Sequence[str] = ()
) -> Iterator[list[subprocess.Popen[bytes]]]:
    """The pod of a work's Deployment as host processes: the bed's cloud nodes are kwok, so
    nothing runs in them. Each container of the workload image (``only``: these) runs its
    entry point with its args and its environment, in a ROS 2 graph of the pod's own
    (``domain``, discovery on localhost, as the relay sidecar keeps it) and with its metrics on
    loopback; stopped (SIGTERM) after, each one's exit checked."""
    procs: list[subprocess.Popen[bytes]] = []
    outs = []
    try:
        for container in deployment["spec"]["template"]["spec"]["containers"]:
            if only and container["name"] not in only:
                continue
            env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "FOGFLEET_"))}
            env |= container_env(deployment, container["name"])
            env |= {"ROS_DOMAIN_ID": str(domain), ENV_METRICS_HOST: "127.0.0.1",
                    ENV_METRICS_PORT: str(free_port())}  # fmt: skip
            out = (logs / f"cloud-{container['name']}.log").open("wb")
            outs.append(out)
            argv = [
                sys.executable,
                "-m",
                "fogfleet.workload",
                *(container.get("args") or ["module"]),
            ]
            procs.append(subprocess.Popen(argv, env=env, stdout=out, stderr=subprocess.STDOUT))
        yield procs
    finally:
        for proc in procs:
            proc.terminate()
        codes = [proc.wait(timeout=20) for proc in procs]
        for out in outs:
            out.close()
    assert codes == [0] * len(procs), [p.read_text()[-1500:] for p in logs.glob("cloud-*.log")]
