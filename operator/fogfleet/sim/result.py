"""What one simulation run measured (multi-robot-edge-cloud-scheduling IV: missed cycle time
rates per module, Fig. 6/8; node CPU utilisation, Fig. 5/7)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["JsonValue", "SimResult"]

JsonValue = float | int | str | None | list["JsonValue"] | dict[str, "JsonValue"]


def _num(x: float) -> float | None:
    """JSON has no NaN: an undefined rate (no cycles) becomes null."""
    return None if math.isnan(x) else float(x)


@dataclass(frozen=True, eq=False)
class SimResult:
    """Outcome of ``simulate``. Rates are missed cycles / cycles; NaN where no cycle ran.

    A cycle belongs to the run when it starts before ``duration_s``. Arrays are read-only and
    indexed like the Problem's instances (I,) and nodes (N,).
    """

    duration_s: float
    seed: int
    cycles: int  # all cycles of all placed instances
    missed: int
    miss_rate: float  # the mean over modules of module_miss_rate (NaN if no cycle ran)
    module_miss_rate: dict[str, float]  # per module name, aggregated over robots and replicas
    module_cycles: dict[str, int]
    module_p95_cycle_s: dict[str, float]  # 95th percentile of the cycle durations, seconds
    instance_labels: tuple[str, ...]  # Problem.label(i)
    instance_modules: tuple[str, ...]  # module name of each instance
    node_names: tuple[str, ...]
    placement: NDArray[np.int64]  # (I,) as simulated, -1 = not run
    instance_cycles: NDArray[np.int64]  # (I,)
    instance_missed: NDArray[np.int64]  # (I,)
    instance_miss_rate: NDArray[np.float64]  # (I,) NaN where no cycle ran
    active_fraction: NDArray[np.float64]  # (I,) measured share of the horizon spent active
    node_utilisation: NDArray[np.float64]  # (N,) busy core-seconds / (capacity * horizon)
    unplaced: tuple[int, ...]  # instances with placement -1 (not run)

    def to_dict(self) -> dict[str, JsonValue]:
        """A JSON-ready summary (NaN -> null), keyed by module, instance label and node name."""
        instances: list[JsonValue] = []
        for i, label in enumerate(self.instance_labels):
            j = int(self.placement[i])
            instances.append(
                {
                    "instance": label,
                    "module": self.instance_modules[i],
                    "node": self.node_names[j] if j >= 0 else None,
                    "cycles": int(self.instance_cycles[i]),
                    "missed": int(self.instance_missed[i]),
                    "miss_rate": _num(float(self.instance_miss_rate[i])),
                    "active_fraction": _num(float(self.active_fraction[i])),
                }
            )
        modules: dict[str, JsonValue] = {
            m: {
                "miss_rate": _num(rate),
                "cycles": self.module_cycles[m],
                "p95_cycle_s": _num(self.module_p95_cycle_s[m]),
            }
            for m, rate in self.module_miss_rate.items()
        }
        nodes: dict[str, JsonValue] = {
            name: float(u) for name, u in zip(self.node_names, self.node_utilisation, strict=True)
        }
        return {
            "duration_s": self.duration_s,
            "seed": self.seed,
            "cycles": self.cycles,
            "missed": self.missed,
            "miss_rate": _num(self.miss_rate),
            "modules": modules,
            "node_utilisation": nodes,
            "instances": instances,
            "unplaced": [self.instance_labels[i] for i in self.unplaced],
        }
