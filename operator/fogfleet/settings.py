"""Operator settings from the environment (prefix ``FOGFLEET_``): the only reader of os.environ.

FOGFLEET_NAMESPACES               comma-separated namespaces to serve; empty: all (cluster-wide)
FOGFLEET_KUBECONFIG               kubeconfig file (default: $KUBECONFIG, ~/.kube/config, in-cluster)
FOGFLEET_LOG_LEVEL                DEBUG | INFO | WARNING | ERROR (default INFO)
FOGFLEET_LOG_FORMAT               plain | full | json (default full)
FOGFLEET_LIVENESS_HOST            default 127.0.0.1 (in a pod: 0.0.0.0 so the kubelet can probe)
FOGFLEET_LIVENESS_PORT            /healthz port; 0 turns it off (default 8080)
FOGFLEET_METRICS_HOST             default 127.0.0.1
FOGFLEET_METRICS_PORT             Prometheus /metrics port; 0 turns it off (default 9090)
FOGFLEET_DRIFT_INTERVAL_SECONDS   how often each fleet is re-checked (default 60)
FOGFLEET_DEBOUNCE_SECONDS         quiet time before a re-plan after related edits (default 2)
FOGFLEET_WORKERS                  worker threads for reconciles and planning (default 4)
FOGFLEET_API_CONCURRENCY          a reconcile's writes (Deployments, Services) in flight (default 8)
FOGFLEET_WATCH_CACHE              true (default): reads come from watch-fed caches, not re-lists
FOGFLEET_STANDALONE               true (default): no kopf peering objects
FOGFLEET_SCHEDULER_POPULATION     defaults for fleets whose spec.scheduler leaves these out
FOGFLEET_SCHEDULER_GENERATIONS    (population, generations, timeBudgetMillis); unset: the
FOGFLEET_SCHEDULER_TIME_BUDGET_MILLIS  CRD's own defaults (100, 100, 20000)
FOGFLEET_PROMETHEUS_URL           Prometheus for SLO-driven scaling (unset: nothing scales)
FOGFLEET_SCALING_INTERVAL_SECONDS how often each scaled module decides (default 15, the HPA's sync)
FOGFLEET_LINK_INTERVAL_SECONDS    how often the robots' links are measured (default 10; needs
                                  FOGFLEET_PROMETHEUS_URL)
FOGFLEET_LINK_NODE_LABEL          Prometheus' label of a pod target's Node (default node)
FOGFLEET_OBSERVE_INTERVAL_SECONDS how often the modules' measured cycles are read for drift
                                  (default 30; needs FOGFLEET_PROMETHEUS_URL)
FOGFLEET_PEERING_NAME             kopf peering name when not standalone
FOGFLEET_LEADER_ELECTION          true: only the holder of a Lease reconciles (several replicas)
FOGFLEET_LEADER_ELECTION_NAMESPACE  the Lease's namespace (the chart sets the pod's namespace)
FOGFLEET_LEADER_ELECTION_LEASE    the Lease's name (default fogfleet-operator)
FOGFLEET_LEADER_ELECTION_IDENTITY this replica's identity (the chart sets the pod's name)
FOGFLEET_LEASE_SECONDS            lease duration: a dead leader is replaced within this + 2 s
"""

from __future__ import annotations

import secrets
import socket
from typing import Annotated, Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["Settings"]


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FOGFLEET_", extra="ignore", frozen=True)

    namespaces: Annotated[list[str], NoDecode] = Field(default_factory=list)
    kubeconfig: str | None = None
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    log_format: Literal["plain", "full", "json"] = "full"
    liveness_host: str = "127.0.0.1"
    liveness_port: Annotated[int, Field(ge=0, le=65535)] = 8080
    metrics_host: str = "127.0.0.1"
    metrics_port: Annotated[int, Field(ge=0, le=65535)] = 9090
    drift_interval_seconds: Annotated[float, Field(gt=0)] = 60.0
    debounce_seconds: Annotated[float, Field(ge=0)] = 2.0
    workers: Annotated[int, Field(ge=1, le=64)] = 4
    api_concurrency: Annotated[int, Field(ge=1, le=64)] = 8
    watch_cache: bool = True
    standalone: bool = True
    peering_name: str = "fogfleet"
    scheduler_population: Annotated[int, Field(ge=4, le=2000)] | None = None
    scheduler_generations: Annotated[int, Field(ge=1, le=10000)] | None = None
    scheduler_time_budget_millis: Annotated[int, Field(ge=100)] | None = None
    prometheus_url: str | None = None
    scaling_interval_seconds: Annotated[float, Field(gt=0)] = 15.0
    link_interval_seconds: Annotated[float, Field(gt=0)] = 10.0
    link_node_label: Annotated[str, Field(pattern=r"^[a-zA-Z_][a-zA-Z0-9_]*$")] = "node"
    observe_interval_seconds: Annotated[float, Field(gt=0)] = 30.0
    leader_election: bool = False
    leader_election_namespace: str = "fogfleet-system"
    leader_election_lease: str = "fogfleet-operator"
    leader_election_identity: str = Field(
        default_factory=lambda: f"{socket.gethostname()}-{secrets.token_hex(3)}"
    )
    lease_seconds: Annotated[int, Field(ge=3, le=300)] = 15

    def scheduler_defaults(self) -> dict[str, int]:
        """Scheduler fields (SchedulerSettings names) that fleets inherit when they omit them."""
        pairs = {
            "population": self.scheduler_population,
            "generations": self.scheduler_generations,
            "time_budget_millis": self.scheduler_time_budget_millis,
        }
        return {k: v for k, v in pairs.items() if v is not None}

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
