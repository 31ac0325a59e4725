"""ROS 2 wiring of a fleet (pure): per-robot discovery servers and what every module is told.

* One Fast DDS discovery server per robot: a Deployment pinned to the robot's own node and a
  ClusterIP Service in front of it (``<fleet>-<robot>-dds``, ``render.names``). Its address is
  the Service's cluster IP once the operator has applied it (no cluster DNS needed), else its
  DNS name (``fogfleet render`` offline).
* Every module container gets the ROS environment (RMW, domain, discovery range, its robot's
  server; a shared module: every robot's) and the ``FOGFLEET_*`` variables the ROS 2 workload
  (``python -m fogfleet.workload``) plays its module from: who and where it is, the CPU it was
  given and its spec (cycle time, activation, topics, the profile rows of its node's hardware).
* Secure defaults for every pod fogfleet renders: non-root, seccomp RuntimeDefault, no
  privilege escalation, every capability dropped, read-only root with an emptyDir on /tmp, no
  ServiceAccount token, the metrics port with probes and Prometheus annotations.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fogfleet.api.labels import DEDICATED_TAINT_KEY, HOSTNAME_KEY, LABEL_COMPONENT, LABEL_ROBOT
from fogfleet.api.names import label_value
from fogfleet.api.v1alpha1.fallback import Fallback
from fogfleet.api.v1alpha1.robotfleet import RosSettings
from fogfleet.api.v1alpha1.softwaremodule import ProfileEntry, SoftwareModule
from fogfleet.contract.dnn import PROFILE_KEY, SPEC_KEY
from fogfleet.contract.env import (
    ENV_CPU,
    ENV_FLEET,
    ENV_HARDWARE_TYPE,
    ENV_MODULE,
    ENV_MODULE_SPEC,
    ENV_NODE,
    ENV_ROBOT,
    ENV_ROLE,
    ENV_TIER,
    ENV_VARIANT,
    METRICS_PORT,
)
from fogfleet.domain.pairs import rows_for
from fogfleet.render.names import (
    discovery_service_name,
    metrics_network_policy_name,
    network_policy_name,
    robot_network_policy_name,
    shared_network_policy_name,
)

Obj = dict[str, Any]

__all__ = [
    "COMPONENT_DISCOVERY",
    "METRICS_PORT",
    "PLANNED_TOLERATION",
    "ROBOT_TOLERATIONS",
    "RosWiring",
    "discovery_servers",
    "fleet_network_policies",
    "module_env",
    "node_affinity",
    "on_the_robot",
    "pod_security",
    "render_discovery",
    "ros_env",
    "service_address",
    "stay_on_robot",
]

PROBE_PORT = 42100  # the discovery server's TCP listener, for the kubelet's probes
COMPONENT_DISCOVERY = "ros-discovery-server"
NON_ROOT_UID = 65532


# A pod pinned to a robot has nowhere else to go: when the robot drops off the network its
# kubelet cannot reach the API server, the node turns unreachable/not-ready, and the default
# NoExecute tolerations (300 s upstream, often less) would have the pod deleted and re-created
# on the same robot once it is back, killing what kept the robot working while it was cut off
# (issue 13; KubeEdge keeps such pods too). Robot-pinned pods tolerate both taints for ever.
ROBOT_TOLERATIONS: tuple[dict[str, str], ...] = (
    {"key": "node.kubernetes.io/unreachable", "operator": "Exists", "effect": "NoExecute"},
    {"key": "node.kubernetes.io/not-ready", "operator": "Exists", "effect": "NoExecute"},
)


# fogfleet chose the node of every pod it renders, so each tolerates the taint that keeps a
# node for planned pods only (``api.labels.DEDICATED_TAINT_KEY``).
PLANNED_TOLERATION: dict[str, str] = {
    "key": DEDICATED_TAINT_KEY,
    "operator": "Exists",
    "effect": "NoSchedule",
}


def stay_on_robot(pod_spec: dict[str, Any]) -> dict[str, Any]:
    """``pod_spec`` with ``ROBOT_TOLERATIONS`` added to its own tolerations."""
    have = list(pod_spec.get("tolerations") or [])
    pod_spec["tolerations"] = have + [dict(t) for t in ROBOT_TOLERATIONS if t not in have]
    return pod_spec


@dataclass(frozen=True)
class RosWiring:
    """The fleet's ROS settings and the discovery server address of each robot."""

    settings: RosSettings
    servers: Mapping[str, str] = field(default_factory=dict)  # robot -> host:port

    def server_for(self, robot: str) -> str:
        """ROS_DISCOVERY_SERVER of an instance: its robot's server, or all (shared)."""
        if robot:
            return self.servers.get(robot, "")
        return ";".join(self.servers[r] for r in sorted(self.servers))


def pod_security() -> tuple[dict[str, Any], dict[str, Any]]:
    """(pod securityContext, container securityContext) of the restricted Pod Security level."""
    pod = {
        "runAsNonRoot": True,
        "runAsUser": NON_ROOT_UID,
        "runAsGroup": NON_ROOT_UID,
        "fsGroup": NON_ROOT_UID,
        "seccompProfile": {"type": "RuntimeDefault"},
    }
    container = {
        "allowPrivilegeEscalation": False,
        "readOnlyRootFilesystem": True,
        "runAsNonRoot": True,
        "runAsUser": NON_ROOT_UID,
        "capabilities": {"drop": ["ALL"]},
        "seccompProfile": {"type": "RuntimeDefault"},
    }
    return pod, container


def _env(pairs: Mapping[str, str]) -> list[dict[str, Any]]:
    return [{"name": k, "value": v} for k, v in pairs.items()]


def _rows(module: SoftwareModule, hardware_type: str, speed_factor: float) -> list[dict[str, Any]]:
    """The rows the pod plays on its node: the planner's own (``domain.pairs.rows_for``)."""
    return [
        {
            "hardwareType": hardware_type or "default",
            "cpu": f"{round(r.cpu * 1000, 3):g}m",
            "meanMillis": round(r.mean * 1e3, 3),
            "stdMillis": round(r.std * 1e3, 3),
        }
        for r in rows_for(module, hardware_type, speed_factor)
    ]


def module_spec_json(
    module: SoftwareModule,
    hardware_type: str,
    node_rows: Mapping[str, ProfileEntry] | None = None,
    fallback: Fallback | None = None,
    remote_cycle_millis: float | None = None,
    speed_factor: float = 1.0,
    split: Mapping[str, Any] | None = None,
    dnn_profile: Sequence[str] | None = None,
) -> str:
    """What the workload needs of the module: cycle, activation, topics, its node's profile.

    ``node_rows`` (node name -> the row it runs with there) is for a Deployment that
    kube-scheduler places (the k8s-default baseline): it learns its node only when it runs, so
    it gets the row of every node it may land on (``profileByNode``). ``remote_cycle_millis``
    is, for a variant's standby, the cycle time of the module it stands in for: the remote's
    silence is counted in the remote's cycles. ``split``: a split network's ``dnn``
    (``render.dnn.split_body``); ``dnn_profile``: its profiling Job's split points to time
    (``contract.dnn.PROFILE_KEY``).
    """
    spec = module.spec
    body: dict[str, Any] = {
        "cycleTimeMillis": spec.cycle_time_millis,
        "activationPercent": spec.activation_percent,
        "topics": spec.topics.model_dump(by_alias=True, mode="json"),
        "profile": _rows(module, hardware_type, speed_factor),
    }
    if node_rows:
        body["profileByNode"] = {n: [row.wire()] for n, row in sorted(node_rows.items())}
    if split is not None:
        body[SPEC_KEY] = dict(split)
    if dnn_profile is not None:
        body[PROFILE_KEY] = {"splitPoints": list(dnn_profile)}
    if fallback is not None:
        body["fallback"] = {
            "silentCycles": fallback.silent_cycles,
            "stepBackCycles": fallback.step_back_cycles,
        }
        if remote_cycle_millis is not None:
            body["fallback"]["remoteCycleTimeMillis"] = remote_cycle_millis
    return json.dumps(body, separators=(",", ":"), sort_keys=True)


def ros_env(wiring: RosWiring, robot: str) -> dict[str, str]:
    """The ROS 2 wiring of a fleet pod that serves ``robot`` ("": every robot): its RMW,
    domain, discovery range and its robot's discovery server (none when the wiring is off)."""
    ros = wiring.settings
    if not ros.enabled:
        return {}
    env = {
        "RMW_IMPLEMENTATION": ros.rmw_implementation,
        "ROS_DOMAIN_ID": str(ros.domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": ros.discovery_range.value,
        # no shared memory between pods: Fast DDS would try it on one node and fail
        "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
    }
    server = wiring.server_for(robot)
    if server:
        env["ROS_DISCOVERY_SERVER"] = server
    return env


def module_env(
    wiring: RosWiring | None,
    *,
    fleet: str,
    robot: str,
    module: SoftwareModule,
    tier: str,
    node: str,
    hardware_type: str,
    cpu: str,
    node_rows: Mapping[str, ProfileEntry] | None = None,
    role: str = "",
    fallback: Fallback | None = None,
    stands_in_for: str = "",
    remote_cycle_millis: float | None = None,
    speed_factor: float = 1.0,
    split: Mapping[str, Any] | None = None,
    workload_role: str = "",
    dnn_profile: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The environment fogfleet owns in a module container (ROS wiring + FOGFLEET_*).

    With ``node_rows`` (kube-scheduler chooses among those nodes) the container reads its node
    from the downward API and has no FOGFLEET_CPU (no limit: it runs the row of its node).
    ``role`` (``remote`` or ``standby``, with the module's ``fallback``) is an instance with an
    on-board fallback (``workload.fallback``); unset for every other instance.
    ``stands_in_for``: a variant's standby runs ``module`` for that module (its name in
    FOGFLEET_MODULE and the metrics, the variant's in FOGFLEET_VARIANT). A split network's
    pods have ``split`` (its ``dnn``) and ``workload_role`` (``head`` or ``tail``, which
    FOGFLEET_ROLE then says instead of ``role``); its profiling Job has ``dnn_profile``.
    """
    env = {
        ENV_FLEET: fleet,
        ENV_ROBOT: robot,
        ENV_MODULE: stands_in_for or module.metadata.name,
        ENV_TIER: tier,
        ENV_NODE: node,
        ENV_HARDWARE_TYPE: hardware_type,
        ENV_CPU: cpu,
        ENV_MODULE_SPEC: module_spec_json(
            module,
            hardware_type,
            node_rows,
            fallback,
            remote_cycle_millis,
            speed_factor,
            split,
            dnn_profile,
        ),
    }
    if workload_role or role:
        env[ENV_ROLE] = workload_role or role
    if stands_in_for:
        env[ENV_VARIANT] = module.metadata.name
    if node_rows:
        del env[ENV_NODE], env[ENV_CPU], env[ENV_HARDWARE_TYPE]
    if wiring is not None:
        env |= ros_env(wiring, robot)
    out: list[dict[str, Any]] = _env(env)
    if node_rows:
        node_ref = {"fieldRef": {"apiVersion": "v1", "fieldPath": "spec.nodeName"}}
        out.insert(4, {"name": ENV_NODE, "valueFrom": node_ref})
    return out


def node_affinity(node_names: Sequence[str]) -> dict[str, Any]:
    term = {
        "matchExpressions": [{"key": HOSTNAME_KEY, "operator": "In", "values": list(node_names)}]
    }
    return {
        "nodeAffinity": {
            "requiredDuringSchedulingIgnoredDuringExecution": {"nodeSelectorTerms": [term]}
        }
    }


def on_the_robot(
    meta: Mapping[str, Any], selector: Mapping[str, str], node_name: str, container: Obj
) -> Obj:
    """A Deployment of one pod of fogfleet's own on a robot's node (``node_name``): the robot's
    discovery server, its relay (``render.relays``). Restricted pod security, no token, /tmp."""
    pod_sc, _ = pod_security()
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": dict(meta),
        "spec": {
            "replicas": 1,
            "selector": {"matchLabels": dict(selector)},
            "strategy": {"type": "Recreate"},
            "template": {
                "metadata": {"labels": dict(selector)},
                "spec": {
                    "affinity": node_affinity([node_name]),
                    "automountServiceAccountToken": False,
                    "enableServiceLinks": False,
                    "securityContext": pod_sc,
                    "containers": [container],
                    "volumes": [{"name": "tmp", "emptyDir": {"sizeLimit": "16Mi"}}],
                    "tolerations": [dict(PLANNED_TOLERATION), *map(dict, ROBOT_TOLERATIONS)],
                },
            },
        },
    }


def render_discovery(
    *,
    fleet: str,
    namespace: str,
    robot: str,
    node_name: str,
    settings: RosSettings,
    labels: Mapping[str, str],
    owner_refs: Sequence[Mapping[str, Any]],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(Service, Deployment) of the robot's discovery server, pinned to the robot's node."""
    name = discovery_service_name(fleet, robot)
    # the robot in the selector: each Service must reach its own robot's server only
    selector = {**labels, LABEL_COMPONENT: COMPONENT_DISCOVERY, LABEL_ROBOT: label_value(robot)}
    meta = {
        "name": name,
        "namespace": namespace,
        "labels": dict(selector),
        **({"ownerReferences": [dict(o) for o in owner_refs]} if owner_refs else {}),
    }
    port = settings.discovery_server_port
    service = {
        "apiVersion": "v1",
        "kind": "Service",
        "metadata": meta,
        "spec": {
            "type": "ClusterIP",
            "selector": selector,
            "ports": [{"name": "dds-udp", "port": port, "targetPort": port, "protocol": "UDP"}],
        },
    }
    _, container_sc = pod_security()
    container = {
        "name": "discovery-server",
        "image": settings.discovery_server_image,
        "args": ["discovery-server", "--port", str(port), "--tcp-port", str(PROBE_PORT)],
        "ports": [
            {"name": "dds-udp", "containerPort": port, "protocol": "UDP"},
            {"name": "dds-tcp", "containerPort": PROBE_PORT, "protocol": "TCP"},
        ],
        "livenessProbe": {"tcpSocket": {"port": "dds-tcp"}, "periodSeconds": 10},
        "readinessProbe": {"tcpSocket": {"port": "dds-tcp"}, "periodSeconds": 5},
        "resources": {
            "requests": {"cpu": "20m", "memory": "64Mi"},
            "limits": {"cpu": "100m", "memory": "128Mi"},
        },
        "securityContext": container_sc,
        "volumeMounts": [{"name": "tmp", "mountPath": "/tmp"}],
    }
    deployment = on_the_robot(meta, selector, node_name, container)
    return service, deployment


def discovery_servers(
    problem: Any,
    settings: RosSettings,
    labels: Mapping[str, str],
    owner_refs: Sequence[Mapping[str, Any]],
) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(robot, Service, Deployment) for every robot of the plan, on the robot's own node."""
    nodes = {n.name: n.node_name for n in problem.nodes}
    robots = sorted({inst.robot for inst in problem.instances if inst.robot})
    return [
        (
            robot,
            *render_discovery(
                fleet=problem.fleet,
                namespace=problem.namespace,
                robot=robot,
                node_name=nodes[robot],
                settings=settings,
                labels=labels,
                owner_refs=owner_refs,
            ),
        )
        for robot in robots
        if robot in nodes
    ]


def service_address(service: Mapping[str, Any]) -> str:
    """host:port of a discovery server: its cluster IP once allocated, else its DNS name."""
    meta, spec = service["metadata"], service.get("spec") or {}
    ip = spec.get("clusterIP")
    host = ip if ip and ip != "None" else f"{meta['name']}.{meta['namespace']}.svc"
    return f"{host}:{spec['ports'][0]['port']}"


def fleet_network_policies(
    *, fleet: str, namespace: str, selector: Mapping[str, str], robots: Sequence[str],
    metrics_ports: Sequence[int], owner_refs: Sequence[Mapping[str, Any]],
) -> list[dict[str, Any]]:  # fmt: skip
    """The fleet's NetworkPolicies: only the flows its plan needs (issue 37, item 9).

    A robot's pods (its modules wherever they run, its standbys, its discovery server) and
    the fleet's shared services (instances of no robot) form groups. A robot's pods talk
    with each other and with the shared services, both ways; shared services talk with every
    pod of the fleet; metrics ports take TCP from anywhere (Prometheus). Nothing else, in or
    out: a pod of one robot cannot reach another robot's pods even knowing their addresses.
    NetworkPolicies add up, so each policy grants one group's flows:

    * ``<fleet>-pods`` (every fleet pod): in from shared pods; out to shared pods. Selecting
      every pod also closes whatever the others do not open.
    * ``<fleet>-metrics`` (every fleet pod, ingress only): metrics ports from anywhere. Its own
      ingress-only policy: kube-router runs a pod's outgoing packets through every policy of
      both types that selects the pod, ingress rules included, so an "any source" metrics
      rule there would let one robot's pods reach another's metrics port.
    * ``<fleet>-shared`` (shared pods): in from and out to every fleet pod.
    * ``<fleet>-<robot>-net`` (one robot's pods): in from and out to that robot's pods.

    Traffic to a Service's cluster IP is translated to a pod address before the policy sees
    it, so the discovery server is reached through its robot's group.
    """
    fleet_pods = dict(selector)
    shared = {**fleet_pods, LABEL_ROBOT: ""}
    meta_extra: dict[str, Any] = {}
    if owner_refs:
        meta_extra["ownerReferences"] = [dict(o) for o in owner_refs]

    def policy(
        name: str, pods: Mapping[str, str], ingress: list[Any], egress: list[Any] | None
    ) -> Any:
        types = ["Ingress", "Egress"] if egress is not None else ["Ingress"]
        return {
            "apiVersion": "networking.k8s.io/v1",
            "kind": "NetworkPolicy",
            "metadata": {
                "name": name,
                "namespace": namespace,
                "labels": dict(fleet_pods),
                **meta_extra,
            },
            "spec": {
                "podSelector": {"matchLabels": dict(pods)},
                "policyTypes": types,
                "ingress": ingress,
                **({"egress": egress} if egress is not None else {}),
            },
        }

    def peers(pods: Mapping[str, str]) -> list[dict[str, Any]]:
        return [{"podSelector": {"matchLabels": dict(pods)}}]

    out = [
        policy(
            network_policy_name(fleet),
            fleet_pods,
            [{"from": peers(shared)}],
            [{"to": peers(shared)}],
        ),
        policy(
            shared_network_policy_name(fleet),
            shared,
            [{"from": peers(fleet_pods)}],
            [{"to": peers(fleet_pods)}],
        ),
    ]
    if metrics_ports:
        ports = [{"protocol": "TCP", "port": p} for p in sorted(set(metrics_ports))]
        out.append(policy(metrics_network_policy_name(fleet), fleet_pods, [{"ports": ports}], None))
    for robot in sorted(set(robots) - {""}):
        own = {**fleet_pods, LABEL_ROBOT: label_value(robot)}
        name = robot_network_policy_name(fleet, robot)
        out.append(policy(name, own, [{"from": peers(own)}], [{"to": peers(own)}]))
    return out
