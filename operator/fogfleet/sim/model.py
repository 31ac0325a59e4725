"""What the simulator adds to the declared profile: the execution model a plan is run under.

The declared model runs every cycle at its profile row and shares a short node's CPU by
processor sharing. What runs differs in two ways (issue 49, measured on the real-node bed):

- **each cycle costs more than its work**: wake-ups, the middleware, the host's other
  processes. The closed loop already measures it per (module, hardware type) as a correction of
  the declared rows, a factor and the cycle's noise (``domain.observed``; ``Learnt.row``).
  ``corrections`` are those, and ``allocation`` applies them to a plan's rows, on a type where
  a module's noise was never measured with the noise it shows elsewhere, as the planner takes
  it (``rows.carry_noise``);
- **the kernel spreads a shortage** instead of stretching every cycle alike: ``spread``, the
  share of a short node's CPU that goes to the job that began executing last (``engine``).

``ExecutionModel()`` is the declared model. A fitted one is written as JSON
(``as_json``/``from_json``) so that a benchmark page can say which model it ran.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fogfleet.domain.problem import Allocation, Problem
from fogfleet.domain.rows import Learnt, carry_noise

from .result import SimResult
from .simulator import simulate

__all__ = ["DECLARED", "ExecutionModel", "under_corrections"]

Key = tuple[str, str]  # (module, hardware type)


def under_corrections(
    problem: Problem, allocation: Allocation, corrections: Mapping[Key, Learnt]
) -> Allocation:
    """``allocation`` (a plan's CPU amounts and its rows) with the execution times each
    instance really has on each node: its rows as the correction of its module there makes
    them (``Learnt.row``; on a type where its noise is not known, the noise it shows
    elsewhere, as the planner takes it: ``rows.carry_noise``)."""
    scale = np.ones((problem.n_instances, problem.n_nodes))
    noise = np.zeros((problem.n_instances, problem.n_nodes))
    carried = carry_noise(corrections, (node.hardware_type for node in problem.nodes))
    for i, inst in enumerate(problem.instances):
        for j, node in enumerate(problem.nodes):
            got = carried.get((inst.module, node.hardware_type), Learnt())
            scale[i, j], noise[i, j] = got.factor, got.noise
    return Allocation(
        allocation.cpu_request,
        allocation.cpu_use,
        allocation.exe_mean * scale,
        np.hypot(allocation.exe_std * scale, noise),
        allocation.has_limit,
    )


@dataclass(frozen=True)
class ExecutionModel:
    """The per-cycle corrections and the CPU spread a plan is simulated under."""

    corrections: Mapping[Key, Learnt] = field(default_factory=dict)
    spread: float = 0.0
    source: str = "declared profile, processor sharing"

    def __post_init__(self) -> None:
        if not 0.0 <= self.spread <= 1.0:
            raise ValueError(f"spread must lie in [0, 1], got {self.spread}")
        for key, got in self.corrections.items():
            if not got.factor > 0.0 or got.noise < 0.0:
                raise ValueError(f"correction {key}: factor must be > 0 and noise >= 0")

    def simulate(
        self,
        problem: Problem,
        placement: NDArray[np.int64],
        allocation: Allocation,
        duration_s: float,
        seed: int,
        *,
        all_active: bool = False,
    ) -> SimResult:
        """``sim.simulate`` of ``placement`` with this model's rows and spread."""
        rows = under_corrections(problem, allocation, self.corrections)
        return simulate(
            problem, placement, rows, duration_s, seed, all_active=all_active, spread=self.spread
        )

    def as_json(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "spread": self.spread,
            "corrections": [
                {
                    "module": module,
                    "hardwareType": hw,
                    "factor": round(got.factor, 4),
                    "noiseMillis": round(got.noise * 1e3, 3),
                    "cycles": round(got.noise_cycles),
                }
                for (module, hw), got in sorted(self.corrections.items())
            ],
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> ExecutionModel:
        """The model ``as_json`` wrote; ValueError naming the field that is wrong."""
        try:
            corrections = {
                (str(c["module"]), str(c["hardwareType"])): Learnt(
                    float(c["factor"]), float(c["noiseMillis"]) / 1e3, float(c["cycles"])
                )
                for c in doc.get("corrections") or []
            }
            return cls(corrections, float(doc["spread"]), str(doc.get("source", "")))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"execution model: missing or malformed field {exc}") from exc


DECLARED = ExecutionModel()
