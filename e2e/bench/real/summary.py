"""bench-real.json's "summary" from its runs (pure): per arm the medians over the completed
runs (a failed run is listed, never counted), nsga2's reduction of k8s-default's median on the
primary endpoint with its bootstrap CI and one-sided Mann-Whitney p, and the issue's targets.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from e2e.bench.real.plot import arm_order, completed, rate
from e2e.bench.real.protocol import K8S, NSGA2, ONBOARD, PRIMARY
from e2e.bench.real.stats import bootstrap_reduction_ci, mann_whitney_less, reduction

__all__ = [
    "CONTROL",
    "ENDPOINTS",
    "LEVEL",
    "RESAMPLES",
    "SEED",
    "TARGETS",
    "TREATED",
    "simulator_agrees",
    "summarise",
]

Run = Mapping[str, Any]

TREATED, CONTROL = NSGA2, K8S
RESAMPLES, LEVEL, SEED = 10000, 0.95, 0
ENDPOINTS = {
    "perception": "missed / cycles pooled over every instance of {perception}",
    "allModules": "the mean over modules of each module's missed / cycles",
}
TARGETS = {
    "reductionAtLeast90": f"reduction {TREATED} vs {CONTROL} >= 90 %",
    "pAtMost005": "one-sided Mann-Whitney p <= 0.05",
    "sixRunsEach": f">= 6 completed runs of {TREATED} and of {CONTROL}",
    "onboardWorst": f"{ONBOARD}'s median above {TREATED}'s and {CONTROL}'s",
}


def _safe(x: float | None) -> float | None:
    """JSON has no NaN: None stands for "no figure"."""
    return None if x is None or math.isnan(x) or math.isinf(x) else float(x)


def _median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def _values(runs: Sequence[Run], arm: str, endpoint: str, kind: str = "measured") -> list[float]:
    """The arm's completed runs' rates on the endpoint, in run order."""
    mine = (r for r in runs if r["scheduler"] == arm and completed(r))
    return [v for v in (rate(r, endpoint, kind) for r in mine) if v is not None]


def simulator_agrees(measured: float | None, simulated: float | None) -> bool:
    """Issue 12's agreement rule: within 25 % relative or 0.5 points, whichever is larger."""
    if measured is None or simulated is None:
        return False
    return abs(measured - simulated) <= max(0.25 * measured, 0.005)


def _endpoint(
    runs: Sequence[Run], arms: Sequence[str], endpoint: str, primary: bool
) -> dict[str, Any]:
    block: dict[str, Any] = {}
    for arm in arms:
        values = _values(runs, arm, endpoint)
        n = sum(1 for r in runs if r["scheduler"] == arm and completed(r))
        block[arm] = {"median": _safe(_median(values)), "runs": n}
        if primary:
            block[arm]["values"] = values
    return block


def _comparison(treated: Sequence[float], control: Sequence[float]) -> dict[str, Any]:
    if not treated or not control:
        return {"reduction": None, "ci95": [None, None], "pValue": None}
    lo, hi = bootstrap_reduction_ci(treated, control, resamples=RESAMPLES, level=LEVEL, seed=SEED)
    return {
        "reduction": _safe(reduction(statistics.median(treated), statistics.median(control))),
        "ci95": [_safe(lo), _safe(hi)],
        "pValue": mann_whitney_less(treated, control),
    }


def _modules(
    runs: Sequence[Run], arms: Sequence[str]
) -> dict[str, dict[str, dict[str, float | None]]]:
    names: set[str] = set()
    for r in filter(completed, runs):
        for kind in ("measured", "simulated"):
            names |= set(((r.get(kind) or {}).get("modules") or {}).keys())
    return {
        m: {
            arm: {k: _safe(_median(_values(runs, arm, m, k))) for k in ("measured", "simulated")}
            for arm in arms
        }
        for m in sorted(names)
    }


def _targets(
    summary: Mapping[str, Any], primary: str, perception: Mapping[str, Any]
) -> dict[str, Any]:
    p = summary[primary]

    def med(arm: str) -> float | None:
        return p[arm]["median"] if arm in p else None

    onboard, worse = med(ONBOARD), [med(TREATED), med(CONTROL)]
    sim = summary["simulatedPerception"]
    return {
        "reductionAtLeast90": p["reduction"] is not None and p["reduction"] >= 0.90,
        "pAtMost005": p["pValue"] is not None and p["pValue"] <= 0.05,
        "sixRunsEach": all(p.get(a, {}).get("runs", 0) >= 6 for a in (TREATED, CONTROL)),
        "onboardWorst": onboard is not None and all(m is not None and onboard > m for m in worse),
        "simulatorAgrees": {
            a: simulator_agrees(perception.get(a, {}).get("median"), sim.get(a))
            for a in (TREATED, CONTROL)
        },
    }


def summarise(runs: Sequence[Run], *, primary: str = PRIMARY) -> dict[str, Any]:
    """bench-real.json's "summary": medians over each arm's completed runs (an arm with none
    is left out), and on the ``primary`` endpoint the runs' values, nsga2's reduction of
    k8s-default's median with its 95 % bootstrap CI and one-sided Mann-Whitney p, and the
    targets. JSON-safe: None where a figure does not exist."""
    arms = [a for a in arm_order(runs) if any(r["scheduler"] == a and completed(r) for r in runs)]
    summary: dict[str, Any] = {
        ep: _endpoint(runs, arms, ep, ep == primary)
        for ep in dict.fromkeys(("perception", "allModules", primary))
    }
    summary[primary] |= _comparison(
        _values(runs, TREATED, primary), _values(runs, CONTROL, primary)
    )
    summary["modules"] = _modules(runs, arms)
    summary["simulatedPerception"] = {
        a: _safe(_median(_values(runs, a, "perception", "simulated"))) for a in arms
    }
    summary["targets"] = _targets(summary, primary, summary["perception"])
    return summary
