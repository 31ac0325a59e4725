"""bench-real.json's "summary" from its runs (pure): per arm the medians over the completed
runs (a failed run is listed, never counted), nsga2's reduction of k8s-default's median on the
primary endpoint with its bootstrap CI and one-sided Mann-Whitney p (and the same against
k8s-requests, ``vsRequests``), and the issues' targets (33, and 49's: at least 50 % below
k8s-requests with p <= 0.05, the reduction against k8s-default's CI lower end >= 90 %, and a
closed loop that never makes a plan worse than nsga2-static's).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from e2e.bench.real.plot import arm_order, completed, rate
from e2e.bench.real.protocol import K8S, NSGA2, ONBOARD, PRIMARY, REQUESTS, STATIC
from e2e.bench.real.stats import bootstrap_reduction_ci, mann_whitney_less, reduction

__all__ = [
    "CONTROL",
    "ENDPOINTS",
    "LEVEL",
    "RESAMPLES",
    "SEED",
    "TARGETS",
    "TREATED",
    "median",
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
LOOP_SLACK = 0.005  # issue 49: no nsga2 run worse than nsga2-static's worst by more (0.5 points)
TARGETS = {
    "reductionAtLeast90": f"reduction {TREATED} vs {CONTROL} >= 90 %",
    "ciLowAtLeast90": f"reduction {TREATED} vs {CONTROL}: 95 % CI lower end >= 90 %",
    "pAtMost005": "one-sided Mann-Whitney p <= 0.05",
    "sixRunsEach": f">= 6 completed runs of {TREATED} and of {CONTROL}",
    "onboardWorst": f"{ONBOARD}'s median above {TREATED}'s and {CONTROL}'s",
    "requestsHalved": f"reduction {TREATED} vs {REQUESTS} >= 50 %, one-sided Mann-Whitney "
    f"p <= 0.05, >= 6 completed runs each",
    "loopNoWorse": f"{TREATED}'s median <= {STATIC}'s, and no {TREATED} run worse than "
    f"{STATIC}'s worst by more than {100 * LOOP_SLACK:g} points",
}
AGREEMENT_ARMS = (TREATED, STATIC, CONTROL, REQUESTS)  # issue 49: the simulator on each


def _safe(x: float | None) -> float | None:
    """JSON has no NaN: None stands for "no figure"."""
    return None if x is None or math.isnan(x) or math.isinf(x) else float(x)


def median(values: Sequence[float]) -> float | None:
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
        block[arm] = {"median": _safe(median(values)), "runs": n}
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
            arm: {k: _safe(median(_values(runs, arm, m, k))) for k in ("measured", "simulated")}
            for arm in arms
        }
        for m in sorted(names)
    }


def _targets(
    summary: Mapping[str, Any],
    primary: str,
    perception: Mapping[str, Any],
    scheduled: frozenset[str] = frozenset(),
) -> dict[str, Any]:
    """The targets; those of an arm the document never ran (k8s-requests, nsga2-static: an
    older protocol) are left out, those of an arm whose runs all failed are missed."""
    p = summary[primary]

    def med(arm: str) -> float | None:
        return p[arm]["median"] if arm in p else None

    onboard, worse = med(ONBOARD), [med(TREATED), med(CONTROL)]
    sim = summary["simulatedPerception"]
    vs = p.get("vsRequests") or {}
    six = {a: p.get(a, {}).get("runs", 0) >= 6 for a in (TREATED, CONTROL, REQUESTS)}
    loop, static = p.get(TREATED, {}).get("values") or [], p.get(STATIC, {}).get("values") or []
    out = {
        "reductionAtLeast90": p["reduction"] is not None and p["reduction"] >= 0.90,
        "ciLowAtLeast90": p["ci95"][0] is not None and p["ci95"][0] >= 0.90,
        "pAtMost005": p["pValue"] is not None and p["pValue"] <= 0.05,
        "sixRunsEach": six[TREATED] and six[CONTROL],
        "onboardWorst": onboard is not None and all(m is not None and onboard > m for m in worse),
        "requestsHalved": vs.get("reduction") is not None
        and vs["reduction"] >= 0.50
        and vs.get("pValue") is not None
        and vs["pValue"] <= 0.05
        and six[TREATED]
        and six[REQUESTS],
        "loopNoWorse": bool(loop and static)
        and statistics.median(loop) <= statistics.median(static)
        and max(loop) <= max(static) + LOOP_SLACK,
        "simulatorAgrees": {
            a: simulator_agrees(perception.get(a, {}).get("median"), sim.get(a))
            for a in AGREEMENT_ARMS
            if a in (TREATED, CONTROL) or a in perception  # the two compared always count
        },
    }
    for key, arm in (("requestsHalved", REQUESTS), ("loopNoWorse", STATIC)):
        if arm not in scheduled:
            del out[key]
    return out


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
    summary[primary]["vsRequests"] = _comparison(
        _values(runs, TREATED, primary), _values(runs, REQUESTS, primary)
    )
    summary["modules"] = _modules(runs, arms)
    summary["simulatedPerception"] = {
        a: _safe(median(_values(runs, a, "perception", "simulated"))) for a in arms
    }
    scheduled = frozenset(str(r["scheduler"]) for r in runs)
    summary["targets"] = _targets(summary, primary, summary["perception"], scheduled)
    return summary
