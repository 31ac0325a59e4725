"""What a workload instance is told by the operator, through its environment (no ROS here)."""

from __future__ import annotations

import json
import math
import random
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "ENV_SPEC",
    "ExecRow",
    "TopicSpec",
    "WorkloadSpec",
    "exec_time",
    "mean_episode_s",
    "sample_exec_seconds",
]

ENV_SPEC = "FOGFLEET_MODULE_SPEC"
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


def exec_time(rows: list[ExecRow], cpu: float) -> ExecRow:
    """The row the module runs with at CPU limit `cpu`: the largest profiled CPU that fits
    (the operator sets the limit to a profiled value), else the smallest."""
    if not rows:
        raise ValueError("no execution-time profile for this hardware type")
    fitting = [r for r in rows if r.cpu <= cpu + 1e-9]
    return max(fitting, key=lambda r: r.cpu) if fitting else min(rows, key=lambda r: r.cpu)


def sample_exec_seconds(row: ExecRow, rng: random.Random) -> float:
    """One cycle's execution time at full share: normal, never below a tenth of the mean."""
    return max(row.mean_s * 0.1, rng.gauss(row.mean_s, row.std_s))


def _quantity(value: Any) -> float:
    """Quantities as the operator renders them: numbers, or strings such as "80Ki" / "500m"."""
    if isinstance(value, int | float):
        return float(value)
    text = str(value).strip()
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "k": 1e3, "M": 1e6, "m": 1e-3}
    for suffix, factor in units.items():
        if text.endswith(suffix):
            return float(text[: -len(suffix)]) * factor
    return float(text)


@dataclass(frozen=True)
class WorkloadSpec:
    fleet: str
    robot: str
    module: str
    tier: str
    node: str
    cpu: float
    cycle_s: float
    activation: float
    subscribes: list[TopicSpec] = field(default_factory=list)
    publishes: list[TopicSpec] = field(default_factory=list)
    profile: list[ExecRow] = field(default_factory=list)

    @property
    def row(self) -> ExecRow:
        return exec_time(self.profile, self.cpu)

    @property
    def workers(self) -> int:
        """Processes that burn CPU in parallel: the profiled CPU, rounded up."""
        return max(1, math.ceil(self.row.cpu - 1e-9))

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
            return cls(
                fleet=env.get("FOGFLEET_FLEET", ""),
                robot=env.get("FOGFLEET_ROBOT", ""),
                module=env.get("FOGFLEET_MODULE", raw.get("module", "module")),
                tier=env.get("FOGFLEET_TIER", "robot"),
                node=env.get("FOGFLEET_NODE", ""),
                cpu=_quantity(env.get("FOGFLEET_CPU", "1")),
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
                        for r in raw.get("profile", [])
                    ),
                    key=lambda r: r.cpu,
                ),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{ENV_SPEC}: {exc!r}") from exc


def _topic(t: Mapping[str, Any]) -> TopicSpec:
    return TopicSpec(t["name"], int(_quantity(t.get("sizeBytes", 64))), _quantity(t["rateHz"]))
