"""What one run records, and the bench-real.json document that holds every run.

A run's record names the run (arm, seed, block, position), says why it failed if it did, and
holds the measured window (per module and pooled over the perception, the primary endpoint),
the simulator's rates for the placement the cluster ran, that placement, and the CPU each part
of the bed used over the window.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from e2e.bench.real.measure import WindowRates
from e2e.bench.real.protocol import PERCEPTION, PRIMARY, REQUESTS, Protocol, ScheduledRun
from e2e.bench.real.scenario import PROFILE, REFERENCE, SCALE, SIGMAS, Scenario, honest_requests
from e2e.bench.real.summary import summarise
from fogfleet.bench.record import machine
from fogfleet.sim.simulator import fleet_miss_rate

__all__ = ["RunResult", "document", "machine", "protocol_json", "requests_json"]


@dataclass
class RunResult:
    """One run as bench-real.json records it (``failed``: why it did not complete)."""

    run: ScheduledRun
    window_s: float
    failed: str | None = None
    measured: WindowRates | None = None
    simulated: dict[str, float] | None = None  # per module
    simulated_cycles: dict[str, int] | None = None
    placement: dict[str, str] | None = None  # robot/module -> node
    cpu: dict[str, str] | None = None  # robot/module -> the CPU the plan gave it (its status)
    ready_s: float | None = None  # apply -> fleet Ready
    corrected: tuple[str, ...] = ()  # what the closed loop learnt in the warm-up
    cpu_seconds: dict[str, float] | None = None  # per part of the bed, over the window

    def as_json(self) -> dict[str, Any]:
        r = self.run
        out: dict[str, Any] = {
            "scheduler": r.arm,
            "seed": r.seed,
            "position": r.position,
            "block": r.block,
            "windowSeconds": self.window_s,
            "failed": self.failed,
            "placement": self.placement,
            "cpu": self.cpu,
            "readySeconds": None if self.ready_s is None else round(self.ready_s, 1),
            "corrected": list(self.corrected),
            "cpuSeconds": self.cpu_seconds,
            "measured": None,
            "simulated": None,
        }
        if self.measured is not None:
            m = self.measured
            missed, cycles = m.pooled(PERCEPTION)
            out["measured"] = {
                PRIMARY: {"missed": missed, "cycles": cycles, "missRate": _rate(missed, cycles)},
                "modules": {
                    k: {"missed": m.missed.get(k, 0), "cycles": c, "missRate": m.modules[k]}
                    for k, c in sorted(m.cycles.items())
                },
                "allModules": m.miss_rate,
            }
        if self.simulated is not None and self.simulated_cycles is not None:
            sim, n = self.simulated, self.simulated_cycles
            pooled = sum(sim[k] * n[k] for k in PERCEPTION if k in n)
            out["simulated"] = {
                PRIMARY: {"missRate": _rate(pooled, sum(n.get(k, 0) for k in PERCEPTION))},
                "modules": {k: {"missRate": v} for k, v in sorted(sim.items())},
                "allModules": fleet_miss_rate(sim),
            }
        return out


def _rate(missed: float, cycles: float) -> float | None:
    return missed / cycles if cycles else None


def document(
    results: Sequence[RunResult],
    protocol: Protocol,
    scenario: Scenario,
    command: str,
    earlier: Sequence[dict[str, Any]] = (),
) -> dict[str, Any]:
    """The bench-real.json document: the bed, the protocol, every run and the summary
    (``earlier``: the runs of a stopped run this one resumes, as it recorded them)."""
    runs = [*earlier, *(r.as_json() for r in results)]
    proto = protocol_json(protocol, scenario)
    return {
        "date": time.strftime("%Y-%m-%d"),
        "machine": machine(),
        "command": command,
        "bed": {"profile": PROFILE, "scale": SCALE, "nodes": scenario.hardware()},
        "protocol": proto,
        "primaryEndpoint": PRIMARY,
        "runs": runs,
        "summary": summarise(runs),
    }


def protocol_json(protocol: Protocol, scenario: Scenario) -> dict[str, Any]:
    """The document's ``protocol``: the protocol, and k8s-requests' requests when it runs."""
    proto = protocol.as_json()
    if protocol.runs.get(REQUESTS):
        proto["k8sRequests"] = requests_json(scenario)
    return proto


def requests_json(scenario: Scenario) -> dict[str, Any]:
    """How the k8s-requests arm's requests were chosen, and what they are (the protocol's
    ``k8sRequests``): computed from the scenario's declared profile rows only, so they were
    fixed before the arm's first run."""
    got = honest_requests(scenario.of_kind("SoftwareModule"))
    return {
        "referenceHardware": REFERENCE,
        "sigmas": SIGMAS,
        "source": "e2e/bench/real/paper/modules.yaml",
        "requests": {m: r.as_json() for m, r in sorted(got.items())},
    }
