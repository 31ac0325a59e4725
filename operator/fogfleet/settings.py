"""Operator settings from the environment (prefix ``FOGFLEET_``): the only reader of os.environ.

Each field's description is what ``fogfleet run --help`` prints beside its variable and
default (:func:`settings_help`), so the help cannot drift from the settings; the table in
docs/operations.md adds the chart's value of each.
"""

from __future__ import annotations

import secrets
import socket
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["Settings", "settings_help"]


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FOGFLEET_", extra="ignore", frozen=True)

    namespaces: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="comma-separated namespaces to serve; empty: all (cluster-wide)",
        json_schema_extra={"shown_default": "all"},
    )
    kubeconfig: str | None = Field(
        None,
        description="kubeconfig file (unset: $KUBECONFIG, ~/.kube/config, then in-cluster)",
    )
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = Field(
        "INFO", description="DEBUG | INFO | WARNING | ERROR"
    )
    log_format: Literal["plain", "full", "json"] = Field("full", description="plain | full | json")
    liveness_host: str = Field(
        "127.0.0.1", description="/healthz address (in a pod: 0.0.0.0, for the kubelet)"
    )
    liveness_port: Annotated[int, Field(ge=0, le=65535)] = Field(
        8080, description="/healthz port; 0 turns it off"
    )
    metrics_host: str = Field("127.0.0.1", description="Prometheus /metrics address")
    metrics_port: Annotated[int, Field(ge=0, le=65535)] = Field(
        9090, description="Prometheus /metrics port; 0 turns it off"
    )
    drift_interval_seconds: Annotated[float, Field(gt=0)] = Field(
        60.0, description="how often each fleet is re-checked"
    )
    debounce_seconds: Annotated[float, Field(ge=0)] = Field(
        2.0, description="quiet time before a re-plan after related edits"
    )
    workers: Annotated[int, Field(ge=1, le=64)] = Field(
        4, description="worker threads for reconciles and planning"
    )
    api_concurrency: Annotated[int, Field(ge=1, le=64)] = Field(
        8, description="a reconcile's writes (Deployments, Services) in flight"
    )
    watch_cache: bool = Field(True, description="reads come from watch-fed caches, not re-lists")
    standalone: bool = Field(True, description="no kopf peering objects")
    peering_name: str = Field("fogfleet", description="kopf peering name when not standalone")
    scheduler_population: Annotated[int, Field(ge=4, le=2000)] | None = Field(
        None,
        description="population of fleets whose spec.scheduler leaves it out (unset: the "
        "CRD's 100)",
    )
    scheduler_generations: Annotated[int, Field(ge=1, le=10000)] | None = Field(
        None,
        description="generations of fleets whose spec.scheduler leaves them out (unset: "
        "the CRD's 100)",
    )
    scheduler_time_budget_millis: Annotated[int, Field(ge=100)] | None = Field(
        None,
        description="time budget of fleets whose spec.scheduler leaves it out (unset: the "
        "CRD's 20000)",
    )
    prometheus_url: str | None = Field(
        None,
        description="Prometheus for SLO-driven scaling, link health and drift (unset: none "
        "of them runs)",
    )
    scaling_interval_seconds: Annotated[float, Field(gt=0)] = Field(
        15.0, description="how often each scaled module decides (the HPA's sync period)"
    )
    rate_window_seconds: Annotated[int, Field(ge=1, le=3600)] = Field(
        10,
        description="rate() window of a predictive module's offered load: shorter follows a "
        "surge sooner but counts fewer requests; keep it at least twice Prometheus' scrape "
        "interval, or rate() finds fewer than two samples and the module reads NoData",
    )
    link_interval_seconds: Annotated[float, Field(gt=0)] = Field(
        10.0, description="how often the robots' links are measured (needs PROMETHEUS_URL)"
    )
    link_node_label: Annotated[str, Field(pattern=r"^[a-zA-Z_][a-zA-Z0-9_]*$")] = Field(
        "node", description="Prometheus' label of a pod target's Node"
    )
    observe_interval_seconds: Annotated[float, Field(gt=0)] = Field(
        30.0,
        description="how often the modules' measured cycles are read for drift (needs "
        "PROMETHEUS_URL)",
    )
    leader_election: bool = Field(
        False, description="only the holder of a Lease reconciles (several replicas)"
    )
    leader_election_namespace: str = Field(
        "fogfleet-system", description="the Lease's namespace (the chart sets the pod's)"
    )
    leader_election_lease: str = Field("fogfleet-operator", description="the Lease's name")
    leader_election_identity: str = Field(
        default_factory=lambda: f"{socket.gethostname()}-{secrets.token_hex(3)}",
        description="this replica's identity (the chart sets the pod's name)",
        json_schema_extra={"shown_default": "host name + 6 random hex digits"},
    )
    lease_seconds: Annotated[int, Field(ge=3, le=300)] = Field(
        15, description="lease duration: a dead leader is replaced within this + 2 s"
    )
    hub_kubeconfig: str | None = Field(
        None,
        description="kubeconfig of the Open Cluster Management hub: instances planned onto a "
        "ComputeNode with spec.managedCluster run there through ManifestWorks (unset: such "
        "nodes are unavailable)",
    )
    cluster_name: str | None = Field(
        None,
        description="this cluster's name among the hub's ManagedClusters, labelled on the "
        "ManifestWorks it writes (needed with HUB_KUBECONFIG)",
    )

    site_router: Annotated[str, Field(pattern=r"^(tcp|tls|quic)/[^/\s]+:[0-9]{1,5}$")] | None = (
        Field(
            None,
            description="the site's Zenoh router (tcp/HOST:PORT) that each robot's relay dials: "
            "the ROS 2 topics of instances in managed clusters cross through it (unset: none "
            "cross; needs HUB_KUBECONFIG)",
        )
    )

    def scheduler_defaults(self) -> dict[str, int]:
        """Scheduler fields (SchedulerSettings names) that fleets inherit when they omit them."""
        pairs = {
            "population": self.scheduler_population,
            "generations": self.scheduler_generations,
            "time_budget_millis": self.scheduler_time_budget_millis,
        }
        return {k: v for k, v in pairs.items() if v is not None}

    @model_validator(mode="after")
    def _hub_needs_a_name(self) -> Settings:
        if self.hub_kubeconfig and not self.cluster_name:
            raise ValueError(
                "FOGFLEET_CLUSTER_NAME: needed with FOGFLEET_HUB_KUBECONFIG (this cluster's "
                "ManagedCluster name on the hub)"
            )
        return self

    @field_validator("namespaces", mode="before")
    @classmethod
    def _split(cls, value: object) -> object:
        if isinstance(value, str):
            return [v.strip() for v in value.split(",") if v.strip()]
        return value

    @field_validator("log_level", mode="before")
    @classmethod
    def _upper(cls, value: object) -> object:
        return value.upper() if isinstance(value, str) else value


def settings_help() -> list[tuple[str, str, str]]:
    """(environment variable, default, description) of every setting, in field order."""
    prefix = str(Settings.model_config.get("env_prefix", ""))
    rows = []
    for name, info in Settings.model_fields.items():
        extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
        shown = extra.get("shown_default")
        if shown is None:
            shown = _shown(info.default)
        rows.append((f"{prefix}{name}".upper(), str(shown), info.description or ""))
    return rows


def _shown(value: object) -> str:
    """A default as one writes it in the environment ("true", "60", "unset")."""
    if value is None:
        return "unset"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)
