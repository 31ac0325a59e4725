"""What a workload instance is told by the operator, through its environment (no ROS here)."""

from __future__ import annotations

import json
import random
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fogfleet.contract.dnn import PROFILE_KEY, SPEC_KEY
from fogfleet.contract.env import (
    ENV_CPU,
    ENV_FLEET,
    ENV_HARDWARE_TYPE,
    ENV_MODULE,
    ENV_NODE,
    ENV_ROBOT,
    ENV_ROLE,
    ENV_TIER,
)
from fogfleet.contract.env import ENV_MODULE_SPEC as ENV_SPEC
from fogfleet.contract.quantity import parse_quantity as _quantity

from .dnn.runspec import DnnRunSpec
from .fallback import Role

__all__ = [
    "ENV_ROLE",
    "ENV_SPEC",
    "ExecRow",
    "TopicSpec",
    "WorkloadSpec",
    "exec_time",
    "mean_episode_s",
    "sample_exec_seconds",
]

# fogfleet.sim.episodes: the same activation episodes the simulator draws (a unit test keeps
# the two equal; the workload image carries no numpy-based simulator).
ACTIVE_PERIOD_S, MIN_ACTIVE_S, MAX_ACTIVE_S = 40.0, 10.0, 30.0


def mean_episode_s(activation: float) -> tuple[float, float]:
    """Mean (on, off) episode lengths for an activation fraction (sim.episodes)."""
    on = min(max(activation * ACTIVE_PERIOD_S, MIN_ACTIVE_S), MAX_ACTIVE_S)
    return on, on * (1.0 - activation) / activation


@dataclass(frozen=True)
class TopicSpec:
    name: str
    size_bytes: int
    rate_hz: float


@dataclass(frozen=True)
class ExecRow:
    """One profile row (Fig. 3): mean and std execution time with `cpu` cores."""

    cpu: float
    mean_s: float
    std_s: float


def exec_time(rows: list[ExecRow], cpu: float | None) -> ExecRow:
    """The row the module runs with at CPU limit `cpu`: the largest profiled CPU that fits
    (the operator sets the limit to a profiled value), else the smallest. Without a limit (the
    k8s-default baseline's plain Deployments) it uses the largest profiled parallelism, as the
    simulator's nominal allocation does (domain.build)."""
    if not rows:
        raise ValueError("no execution-time profile for this hardware type")
    if cpu is None:
        return max(rows, key=lambda r: r.cpu)
    fitting = [r for r in rows if r.cpu <= cpu + 1e-9]
    return max(fitting, key=lambda r: r.cpu) if fitting else min(rows, key=lambda r: r.cpu)


def sample_exec_seconds(row: ExecRow, rng: random.Random) -> float:
    """One cycle's execution time at full share: normal, never below a tenth of the mean."""
    return max(row.mean_s * 0.1, rng.gauss(row.mean_s, row.std_s))


@dataclass(frozen=True)
class WorkloadSpec:
    fleet: str
    robot: str
    module: str
    tier: str
    node: str
    cpu: float | None  # the CPU limit; None: no limit (a plain Deployment)
    cycle_s: float
    activation: float
    subscribes: list[TopicSpec] = field(default_factory=list)
    publishes: list[TopicSpec] = field(default_factory=list)
    profile: list[ExecRow] = field(default_factory=list)
    role: Role = Role.PRIMARY
    silent_cycles: int = 3  # a standby takes over after this many cycles without the remote
    step_back_cycles: int = 10  # and steps back after the remote has delivered this long
    remote_cycle_s: float | None = None  # a variant's standby: the remote module's cycle
    hardware_type: str = ""  # the node's (FOGFLEET_HARDWARE_TYPE): a label of its exec times
    # experiments only (``module --work-factor``): the module's real work is this many times
    # its profile row, as when a declared profile is optimistic (issue 10's closed loop)
    work_factor: float = 1.0
    # the module's own work (``module --cpu-work MILLIS``): seconds of CPU a cycle, burnt as
    # fast as the CPU limit allows; None: it plays its profile row
    cpu_work_s: float | None = None
    # a split DNN module (the spec's "dnn" key, contract.dnn): its network, bounds and plan
    dnn: DnnRunSpec | None = None
    # a split DNN module's profiling Job (the spec's "dnnProfile" key, contract.dnn): the
    # split points whose models it times, in order; None: not such a Job
    dnn_profile: tuple[str, ...] | None = None

    @property
    def cpu_label(self) -> str:
        """The CPU limit as its exec-time label: millicores ("100m"), "" without a limit."""
        return "" if self.cpu is None else f"{round(self.cpu * 1000)}m"

    @property
    def takeover_cycle_s(self) -> float:
        """The cycle the remote's silence is counted in (the remote module's)."""
        return self.remote_cycle_s if self.remote_cycle_s is not None else self.cycle_s

    @property
    def row(self) -> ExecRow:
        return exec_time(self.profile, self.cpu)

    @classmethod
    def from_env(cls, env: Mapping[str, str]) -> WorkloadSpec:
        try:
            raw = json.loads(env[ENV_SPEC])
        except KeyError as exc:
            raise ValueError(f"{ENV_SPEC} is not set: the operator renders it") from exc
        except json.JSONDecodeError as exc:
            raise ValueError(f"{ENV_SPEC}: not JSON ({exc})") from exc
        try:
            topics = raw.get("topics") or {}
            node = env.get(ENV_NODE, "")
            # a plain Deployment learns its node only when it runs (the downward API), so its
            # spec carries the rows of every node it may land on
            rows = (raw.get("profileByNode") or {}).get(node, raw.get("profile", []))
            cpu = env.get(ENV_CPU, "")
            fallback = raw.get("fallback") or {}
            role = env.get(ENV_ROLE, Role.PRIMARY.value)
            if role not in {r.value for r in Role}:
                raise ValueError(f"{ENV_ROLE}={role!r}: one of {', '.join(r.value for r in Role)}")
            return cls(
                fleet=env.get(ENV_FLEET, ""),
                robot=env.get(ENV_ROBOT, ""),
                module=env.get(ENV_MODULE, raw.get("module", "module")),
                tier=env.get(ENV_TIER, "robot"),
                node=node,
                cpu=_quantity(cpu) if cpu else None,
                cycle_s=_quantity(raw["cycleTimeMillis"]) / 1e3,
                activation=_quantity(raw.get("activationPercent", 100)) / 100.0,
                subscribes=[_topic(t) for t in topics.get("subscribes", [])],
                publishes=[_topic(t) for t in topics.get("publishes", [])],
                profile=sorted(
                    (
                        ExecRow(
                            _quantity(r["cpu"]),
                            _quantity(r["meanMillis"]) / 1e3,
                            _quantity(r.get("stdMillis", 0)) / 1e3,
                        )
                        for r in rows
                    ),
                    key=lambda r: r.cpu,
                ),
                role=Role(role),
                silent_cycles=_positive(fallback, "silentCycles", 3),
                step_back_cycles=_positive(fallback, "stepBackCycles", 10),
                hardware_type=env.get(ENV_HARDWARE_TYPE, ""),
                remote_cycle_s=(
                    _quantity(fallback["remoteCycleTimeMillis"]) / 1e3
                    if "remoteCycleTimeMillis" in fallback
                    else None
                ),
                dnn=DnnRunSpec.from_raw(raw) if SPEC_KEY in raw else None,
                dnn_profile=_dnn_profile(raw),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{ENV_SPEC}: {exc!r}") from exc


def _dnn_profile(raw: Mapping[str, Any]) -> tuple[str, ...] | None:
    """The split points a profiling Job times (``PROFILE_KEY``'s ``splitPoints``: a list of
    names), None when the spec has no ``PROFILE_KEY``."""
    if PROFILE_KEY not in raw:
        return None
    body = raw[PROFILE_KEY]
    names = body.get("splitPoints") if isinstance(body, Mapping) else None
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        raise ValueError(
            f"{PROFILE_KEY}.splitPoints: {names!r} is not a list of split points' names"
        )
    return tuple(names)


def _positive(raw: Mapping[str, Any], key: str, default: int) -> int:
    value = int(raw.get(key, default))
    if value < 1:
        raise ValueError(f"fallback.{key}: {value} is not a positive number of cycles")
    return value


def _topic(t: Mapping[str, Any]) -> TopicSpec:
    return TopicSpec(t["name"], int(_quantity(t.get("sizeBytes", 64))), _quantity(t["rateHz"]))
