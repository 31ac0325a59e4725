"""The pod-template subset a SoftwareModule may set: what ROS 2 modules need (maps and
parameters as volumes, devices, ports, probes, sidecars, tolerations for tainted robot
computers, pull secrets), in the Kubernetes API's own field names so a user can copy them from
a Deployment. Placement, CPU and the ROS 2 wiring stay fogfleet's (``softwaremodule`` refuses
them by name, see ``OWNED_POD_FIELDS``).

Each type is a structural schema the API server validates on ``kubectl apply``; the models
check what CEL in the CRD checks too (one volume source, probe handler), naming the field.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, model_validator

from .base import FogModel, Quantity

__all__ = [
    "OWNED_POD_FIELDS",
    "ContainerBase",
    "ContainerPort",
    "EnvFromSource",
    "EnvVar",
    "EnvVarSource",
    "KeyRef",
    "Probe",
    "SecurityContext",
    "Sidecar",
    "Toleration",
    "Volume",
    "VolumeMount",
]

DnsLabel = Annotated[
    str, Field(min_length=1, max_length=63, pattern=r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")
]
Port = Annotated[int, Field(ge=1, le=65535)]
_PORT_NAME = re.compile(r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")


def _check_port_ref(value: Any) -> Any:
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ValueError("must be a port number or a container port's name")
    if isinstance(value, int) and not 1 <= value <= 65535:
        raise ValueError(f"{value} is not a port number (1-65535)")
    if isinstance(value, str) and not (len(value) <= 15 and _PORT_NAME.match(value)):
        raise ValueError(f"{value!r} is not a port name (lower-case, at most 15 characters)")
    return value


PortRef = Annotated[
    int | str,
    BeforeValidator(_check_port_ref),
    Field(
        json_schema_extra={
            "x-kubernetes-int-or-string": True,
            "pattern": _PORT_NAME.pattern,
            "minimum": 1,
            "maximum": 65535,
        }
    ),
]
"""A port number or a container port's name (Kubernetes' IntOrString)."""

OWNED_POD_FIELDS = {
    "affinity": "the pod's placement is the plan's (node affinity); use spec.requirements",
    "nodeSelector": "the pod's placement is the plan's (node affinity); use spec.requirements",
    "nodeName": "the pod's placement is the plan's (node affinity); use spec.requirements",
    "resources": "CPU comes from the plan and memory from spec.resources; device-plugin "
    "resources go in template.extraResources",
    "labels": "fogfleet labels every pod (fleet, robot, module, instance)",
    "replicas": "replicas of a shared module are spec.replicas or spec.scaling",
}
"""PodTemplate/container fields fogfleet sets itself, with what to use instead."""


class KeyRef(FogModel):
    """One key of a ConfigMap or Secret."""

    name: Annotated[str, Field(min_length=1, max_length=253)]
    """The ConfigMap or Secret (same namespace)."""
    key: Annotated[str, Field(min_length=1)]
    """The key."""
    optional: bool | None = None
    """Start the container even when it is missing."""


class FieldRef(FogModel):
    """A field of the pod itself (metadata.name, spec.nodeName, status.podIP...)."""

    field_path: Annotated[str, Field(min_length=1)]
    """The field's path."""


class EnvVarSource(FogModel):
    """Where a variable's value comes from (set exactly one)."""

    secret_key_ref: KeyRef | None = None
    """A key of a Secret."""
    config_map_key_ref: KeyRef | None = None
    """A key of a ConfigMap."""
    field_ref: FieldRef | None = None
    """A field of the pod."""

    @model_validator(mode="after")
    def _one(self) -> EnvVarSource:
        if (
            sum(
                x is not None
                for x in (self.secret_key_ref, self.config_map_key_ref, self.field_ref)
            )
            != 1
        ):
            raise ValueError("set exactly one of secretKeyRef, configMapKeyRef, fieldRef")
        return self


class NamedRef(FogModel):
    """A ConfigMap or Secret by name."""

    name: Annotated[str, Field(min_length=1, max_length=253)]
    """Its name (same namespace)."""
    optional: bool | None = None
    """Start the container even when it is missing."""


class EnvFromSource(FogModel):
    """Every key of a ConfigMap or Secret as environment variables (set one of the two)."""

    config_map_ref: NamedRef | None = None
    """The ConfigMap."""
    secret_ref: NamedRef | None = None
    """The Secret."""
    prefix: str | None = None
    """Prepended to every key."""

    @model_validator(mode="after")
    def _one(self) -> EnvFromSource:
        if (self.config_map_ref is None) == (self.secret_ref is None):
            raise ValueError("set exactly one of configMapRef, secretRef")
        return self


class ContainerPort(FogModel):
    """A port the container listens on."""

    name: (
        Annotated[
            str, Field(min_length=1, max_length=15, pattern=r"^[a-z0-9]([-a-z0-9]*[a-z0-9])?$")
        ]
        | None
    ) = None
    """Its name (metrics is fogfleet's when metricsPort is set)."""
    container_port: Port
    """The port number."""
    protocol: Literal["TCP", "UDP", "SCTP"] = "TCP"
    """TCP, UDP or SCTP."""


class VolumeMount(FogModel):
    """Where a volume appears in the container."""

    name: DnsLabel
    """The volume (from template.volumes; tmp is fogfleet's writable /tmp)."""
    mount_path: Annotated[str, Field(min_length=1, pattern=r"^/")]
    """Absolute path in the container."""
    read_only: bool | None = None
    """Mount read-only."""
    sub_path: str | None = None
    """A path inside the volume to mount instead of its root."""


class KeyToPath(FogModel):
    """One key of a ConfigMap or Secret volume as a file."""

    key: Annotated[str, Field(min_length=1)]
    """The key."""
    path: Annotated[str, Field(min_length=1)]
    """The file's path relative to the mount."""


class ConfigMapVolume(FogModel):
    """A ConfigMap as files (parameters, maps)."""

    name: Annotated[str, Field(min_length=1, max_length=253)]
    """The ConfigMap (same namespace)."""
    items: list[KeyToPath] | None = None
    """Keys to project (default: all)."""
    optional: bool | None = None
    """Start the pod even when it is missing."""


class SecretVolume(FogModel):
    """A Secret as files (certificates, keys)."""

    secret_name: Annotated[str, Field(min_length=1, max_length=253)]
    """The Secret (same namespace)."""
    items: list[KeyToPath] | None = None
    """Keys to project (default: all)."""
    optional: bool | None = None
    """Start the pod even when it is missing."""


class EmptyDirVolume(FogModel):
    """Scratch space that lives as long as the pod."""

    medium: Literal["", "Memory"] | None = None
    """Memory: a tmpfs (counts against the memory limit)."""
    size_limit: Quantity | None = None
    """Most bytes it may hold ("256Mi")."""


class HostPathVolume(FogModel):
    """A file or directory of the node (a device such as /dev/video0, a map cache)."""

    path: Annotated[str, Field(min_length=1, pattern=r"^/")]
    """Absolute path on the node."""
    type: (
        Literal[
            "", "DirectoryOrCreate", "Directory", "FileOrCreate", "File", "Socket",
            "CharDevice", "BlockDevice",
        ]
        | None
    ) = None  # fmt: skip
    """What must exist there (CharDevice for /dev/video0)."""


class ClaimVolume(FogModel):
    """A PersistentVolumeClaim (maps, recorded bags)."""

    claim_name: Annotated[str, Field(min_length=1, max_length=253)]
    """The claim (same namespace)."""
    read_only: bool | None = None
    """Mount read-only."""


class Volume(FogModel):
    """A volume of the pod; set its name and exactly one source."""

    name: DnsLabel
    """Its name, referenced by volumeMounts (tmp is fogfleet's)."""
    config_map: ConfigMapVolume | None = None
    """A ConfigMap."""
    secret: SecretVolume | None = None
    """A Secret."""
    empty_dir: EmptyDirVolume | None = None
    """Scratch space."""
    host_path: HostPathVolume | None = None
    """A path of the node (needs a node the module is pinned to by its requirements)."""
    persistent_volume_claim: ClaimVolume | None = None
    """A PersistentVolumeClaim."""

    @model_validator(mode="after")
    def _one_source(self) -> Volume:
        sources = (
            self.config_map, self.secret, self.empty_dir, self.host_path,
            self.persistent_volume_claim,
        )  # fmt: skip
        if sum(s is not None for s in sources) != 1:
            raise ValueError(
                f"{self.name}: set exactly one of configMap, secret, emptyDir, hostPath, "
                "persistentVolumeClaim"
            )
        if self.name == "tmp":
            raise ValueError("name: tmp is fogfleet's writable /tmp; choose another name")
        return self


class ExecAction(FogModel):
    """Run a command in the container; exit 0 is healthy."""

    command: Annotated[list[str], Field(min_length=1)]
    """The command and its arguments."""


class HttpGetAction(FogModel):
    """An HTTP GET; 200-399 is healthy."""

    path: str = "/"
    """The path."""
    port: PortRef
    """A port number or a container port's name."""


class TcpSocketAction(FogModel):
    """A TCP connect; an open port is healthy."""

    port: PortRef
    """A port number or a container port's name."""


class Probe(FogModel):
    """A health check; set exactly one of exec, httpGet, tcpSocket."""

    exec: ExecAction | None = None
    """Run a command."""
    http_get: HttpGetAction | None = None
    """GET a path."""
    tcp_socket: TcpSocketAction | None = None
    """Connect to a port."""
    initial_delay_seconds: Annotated[int, Field(ge=0)] | None = None
    """Seconds after start before the first check."""
    period_seconds: Annotated[int, Field(ge=1)] | None = None
    """Seconds between checks."""
    timeout_seconds: Annotated[int, Field(ge=1)] | None = None
    """Seconds a check may take."""
    failure_threshold: Annotated[int, Field(ge=1)] | None = None
    """Failed checks in a row before the container counts as failed."""

    @model_validator(mode="after")
    def _one_handler(self) -> Probe:
        if sum(h is not None for h in (self.exec, self.http_get, self.tcp_socket)) != 1:
            raise ValueError("set exactly one of exec, httpGet, tcpSocket")
        return self


class Capabilities(FogModel):
    """Linux capabilities added to what fogfleet leaves (it drops ALL)."""

    add: list[Annotated[str, Field(pattern=r"^[A-Z_]+$")]] = Field(default_factory=list)
    """Capabilities to add (NET_ADMIN, SYS_NICE...)."""


class SecurityContext(FogModel):
    """Exceptions to fogfleet's restricted defaults (non-root uid 65532, no privilege
    escalation, every capability dropped, seccomp RuntimeDefault, read-only root)."""

    run_as_user: Annotated[int, Field(ge=0)] | None = None
    """Run as this uid (0 only with runAsNonRoot false)."""
    run_as_group: Annotated[int, Field(ge=0)] | None = None
    """Run with this gid."""
    run_as_non_root: bool | None = None
    """Refuse to start as root. Default: true."""
    read_only_root_filesystem: bool | None = None
    """Read-only root filesystem. Default: true."""
    privileged: bool | None = None
    """Full access to the node's devices (a camera without a device plugin). Avoid."""
    capabilities: Capabilities | None = None
    """Capabilities to add."""
    supplemental_groups: list[Annotated[int, Field(ge=0)]] | None = None
    """Extra groups of the pod (video, dialout for devices)."""

    @model_validator(mode="after")
    def _root_is_explicit(self) -> SecurityContext:
        if self.run_as_user == 0 and self.run_as_non_root is not False:
            raise ValueError(
                "runAsUser: 0 is root; set runAsNonRoot: false as well if the module must run "
                "as root (the kubelet refuses to start it otherwise)"
            )
        return self


class Toleration(FogModel):
    """Lets the pod run on a node with a matching taint (robot computers often have one)."""

    key: str | None = None
    """The taint's key (empty with operator Exists: every taint)."""
    operator: Literal["Exists", "Equal"] = "Equal"
    """Equal (key and value) or Exists (key only)."""
    value: str | None = None
    """The taint's value (operator Equal)."""
    effect: Literal["", "NoSchedule", "PreferNoSchedule", "NoExecute"] | None = None
    """The taint effect to tolerate (empty: all)."""
    toleration_seconds: Annotated[int, Field(ge=0)] | None = None
    """How long a NoExecute taint is tolerated."""


class EnvVar(FogModel):
    """An environment variable of a container: a value, or valueFrom."""

    name: Annotated[str, Field(min_length=1)]
    """Variable name; FOGFLEET_*, ROS_*, RMW_*, FASTDDS_* and FASTRTPS_* belong to fogfleet."""
    value: str = ""
    """Variable value."""
    value_from: EnvVarSource | None = None
    """Take the value from a Secret, a ConfigMap or the pod (instead of value)."""

    @model_validator(mode="after")
    def _value_or_source(self) -> EnvVar:
        if self.value and self.value_from is not None:
            raise ValueError(f"{self.name}: set value or valueFrom, not both")
        return self


class ContainerBase(FogModel):
    """What the module's container and its sidecars both say: image, entry point, environment,
    ports and the metrics contract's port."""

    image: Annotated[str, Field(min_length=1)]
    """Container image (e.g. ghcr.io/fogfleet/ros2-module:0.1.0)."""
    image_pull_policy: Literal["Always", "IfNotPresent", "Never"] | None = None
    """Kubernetes imagePullPolicy (default: Kubernetes' own, from the image tag)."""
    command: list[str] = Field(default_factory=list)
    """Entrypoint override (default: the image's)."""
    args: list[str] = Field(default_factory=list)
    """Arguments (default: the image's)."""
    env: list[EnvVar] = Field(default_factory=list)
    """Extra environment variables; names fogfleet sets are refused."""
    ports: list[ContainerPort] = Field(default_factory=list)
    """Ports it listens on (besides metricsPort)."""
    metrics_port: Port | None = None
    """Port on which it serves the metrics contract (/metrics) and /healthz: fogfleet then adds
    the port, liveness and readiness probes and Prometheus scrape annotations. The ROS 2
    workload image serves 9100."""


class Sidecar(ContainerBase):
    """An extra container in every instance's pod (a bridge, a recorder, fogfleet's cycle-time
    probe). It gets the module's ROS 2 wiring, fogfleet's restricted security context and the
    resources it asks for; the plan's CPU is the module container's."""

    name: DnsLabel
    """Container name (unique in the pod)."""
    volume_mounts: list[VolumeMount] = Field(default_factory=list)
    """Volumes it mounts (besides /tmp)."""
    cpu: Quantity = "50m"
    """CPU request and limit, in cores."""
    memory: Quantity = "128Mi"
    """Memory request and limit, in bytes."""
