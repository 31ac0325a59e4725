"""``SoftwareModule.spec.template``: the module's container and the pod-template subset it
may set (``podtemplate``), with what fogfleet owns refused by name."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, model_validator

from .base import FogModel, Quantity, refuse_duplicates
from .podtemplate import (
    OWNED_POD_FIELDS,
    ContainerBase,
    EnvFromSource,
    Probe,
    SecurityContext,
    Sidecar,
    Toleration,
    Volume,
    VolumeMount,
)

__all__ = ["RESERVED_ENV_PREFIXES", "ContainerTemplate", "LocalRef"]


class LocalRef(FogModel):
    """An object of the module's namespace, by name."""

    name: Annotated[str, Field(min_length=1, max_length=253)]
    """Its name."""


# Environment fogfleet owns in every module container (the ROS wiring and FOGFLEET_*).
RESERVED_ENV_PREFIXES = ("FOGFLEET_", "ROS_", "RMW_", "FASTDDS_", "FASTRTPS_")


def _reserved_env(names: list[str], field: str) -> None:
    for k, name in enumerate(names):
        if name.startswith(RESERVED_ENV_PREFIXES):
            raise ValueError(
                f"{field}[{k}].name: {name} is set by fogfleet (the ROS 2 wiring and "
                f"FOGFLEET_* variables: {', '.join(RESERVED_ENV_PREFIXES)}); configure it "
                "in the RobotFleet's spec.ros instead"
            )


class ContainerTemplate(ContainerBase):
    """The module's pod: its container and the pod-template subset ROS 2 modules need.
    fogfleet adds placement (node affinity), CPU, memory, labels and the ROS 2 wiring, and
    restricted security defaults wherever this template says nothing."""

    env_from: list[EnvFromSource] = Field(default_factory=list)
    """Every key of a ConfigMap or Secret as variables."""
    volumes: list[Volume] = Field(default_factory=list)
    """Volumes of the pod: parameters and maps (ConfigMap, PVC), devices (hostPath), scratch."""
    volume_mounts: list[VolumeMount] = Field(default_factory=list)
    """Where the volumes appear in the module's container (a writable /tmp is always there)."""
    liveness_probe: Probe | None = None
    """Restart the container when this fails (default with metricsPort: GET /healthz)."""
    readiness_probe: Probe | None = None
    """Count the pod ready when this passes (default with metricsPort: GET /healthz)."""
    startup_probe: Probe | None = None
    """Hold the other probes until this passes (slow-starting modules)."""
    security_context: SecurityContext | None = None
    """Exceptions to the restricted defaults (non-root, no privilege escalation, no
    capabilities, seccomp RuntimeDefault, read-only root filesystem)."""
    extra_resources: dict[str, Quantity] = Field(default_factory=dict)
    """Device-plugin resources requested and limited, e.g. {"squat.ai/video": 1}; GPUs come
    from spec.resources.gpu."""
    tolerations: list[Toleration] = Field(default_factory=list)
    """Taints the pod tolerates (robot computers are often tainted for their own modules)."""
    image_pull_secrets: list[LocalRef] = Field(default_factory=list)
    """Secrets to pull private images with."""
    service_account_name: Annotated[str, Field(min_length=1, max_length=253)] | None = None
    """The pod's ServiceAccount (default: the namespace's default)."""
    automount_service_account_token: bool = False
    """Mount the ServiceAccount's API token (only modules that call the Kubernetes API)."""
    sidecars: list[Sidecar] = Field(default_factory=list)
    """Extra containers in the pod (e.g. fogfleet's cycle-time probe)."""

    def metrics_ports(self) -> list[int]:
        """Every port serving the metrics contract: the module's and its sidecars'."""
        ports = [self.metrics_port, *(c.metrics_port for c in self.sidecars)]
        return [p for p in ports if p]

    @model_validator(mode="before")
    @classmethod
    def _owned_fields(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for key, why in OWNED_POD_FIELDS.items():
                if key in data:
                    raise ValueError(f"{key}: set by fogfleet ({why})")
        return data

    @model_validator(mode="after")
    def _consistent(self) -> ContainerTemplate:
        _reserved_env([e.name for e in self.env], "env")
        for k, car in enumerate(self.sidecars):
            _reserved_env([e.name for e in car.env], f"sidecars[{k}].env")
        volumes = {v.name for v in self.volumes}
        refuse_duplicates([v.name for v in self.volumes], "volumes")
        refuse_duplicates([c.name for c in self.sidecars], "sidecars")
        mounts = [("volumeMounts", m) for m in self.volume_mounts] + [
            (f"sidecars[{k}].volumeMounts", m)
            for k, car in enumerate(self.sidecars)
            for m in car.volume_mounts
        ]
        for field, mount in mounts:
            if mount.name not in volumes:
                raise ValueError(
                    f"{field}: volume {mount.name} is not in volumes "
                    f"({', '.join(sorted(volumes)) or 'none'})"
                )
            if mount.mount_path == "/tmp":
                raise ValueError(f"{field}: /tmp is fogfleet's writable scratch; mount elsewhere")
        ports = [p.container_port for p in self.ports] + [
            p.container_port for car in self.sidecars for p in car.ports
        ]
        ports += [x for x in [self.metrics_port] if x] + [
            car.metrics_port for car in self.sidecars if car.metrics_port
        ]
        refuse_duplicates(ports, "ports")
        if self.metrics_port and any(p.name == "metrics" for p in self.ports):
            raise ValueError("ports: the name metrics is fogfleet's (metricsPort)")
        return self
