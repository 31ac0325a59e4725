"""What the fleets' modules really do, from Prometheus, and drift (issue 10).

Every ``period_seconds`` the operator reads, per namespace it planned fleets in:

- each module's execution times by hardware type and CPU limit
  (``fogfleet_execution_time_seconds``: count, mean, 95th percentile over the fleet's
  ``spec.drift.windowSeconds``) and its cycles and misses there
  (``fogfleet_cycle_time_seconds_count``, ``fogfleet_missed_cycles_total``) into the
  SoftwareModule's ``status.observed``;
- each fleet's measured miss rate per module (``fogfleet_missed_cycles_total`` over
  ``fogfleet_cycle_time_seconds_count`` of the fleet's pods, known by their Deployments' names:
  ``render.names.pod_deployment``) since its last plan, at most the window, against the plan's
  prediction (``domain.observed.drifting``).

A module that drifts for ``forSeconds`` (and ``minIntervalSeconds`` after the fleet's last
re-plan for drift) gets its ``status.profileCorrection`` from its observations
(``domain.observed.correction``: a factor and the cycle's noise, fitted around the fleet's
plan); so do the fleet's other measured modules, since it re-plans anyway. The
SoftwareModule's watch event re-plans every fleet that runs it, with its declared rows so
corrected. The fleet says so in ``status.measured``, its ``Drift`` condition and Events; each
module in an Event of its own.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

from fogfleet import GROUP, VERSION
from fogfleet.adapters.ports import SeriesPort
from fogfleet.api.labels import ROLE_STANDBY
from fogfleet.api.loader import Catalog, parse_object
from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.base import parse_cpu
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.controllers.deps import Deps
from fogfleet.controllers.state import DriftWatch, FleetKey, FleetState
from fogfleet.domain.miss_rates import format_miss_rate
from fogfleet.domain.observed import (
    ModuleDrift,
    Observation,
    correction,
    declared_row,
    drift_due,
    drifting,
    miss_budget,
    timings,
)
from fogfleet.domain.onboard import OnboardNeed, onboard_needs
from fogfleet.domain.pairs import profile_rows
from fogfleet.domain.problem import Problem
from fogfleet.domain.rows import Learnt
from fogfleet.errors import DependencyUnavailable, FogfleetError
from fogfleet.render.names import deployment_name, pod_deployment
from fogfleet.scheduling.decision import Decision
from fogfleet.scheduling.objectives import module_miss_rates
from fogfleet.scheduling.stickiness import loads
from fogfleet.snapshot.objects import recorded_corrections

__all__ = [
    "ObservedDeps",
    "declared_rows",
    "describe",
    "drift_watch",
    "observe",
    "read_observations",
]

log = logging.getLogger(__name__)
Obj = dict[str, Any]
FIELD = "status.observed"
MIN_WINDOW_S = 20  # a miss rate over less (a few scrapes) says nothing yet
_BY = "module, hardware_type, cpu"
EXEC_COUNT = (
    'sum by ({by}) (increase(fogfleet_execution_time_seconds_count{{namespace="{ns}"}}[{w}s]))'
)
EXEC_SUM = 'sum by ({by}) (increase(fogfleet_execution_time_seconds_sum{{namespace="{ns}"}}[{w}s]))'
EXEC_P95 = (
    "histogram_quantile(0.95, sum by (le, {by}) "
    '(increase(fogfleet_execution_time_seconds_bucket{{namespace="{ns}"}}[{w}s])))'
)
CYCLE_COUNT = (
    'sum by ({by}) (increase(fogfleet_cycle_time_seconds_count{{namespace="{ns}"}}[{w}s]))'
)
CYCLE_MISSED = 'sum by ({by}) (increase(fogfleet_missed_cycles_total{{namespace="{ns}"}}[{w}s]))'
# per pod, of the pods whose names begin as the fleet's Deployments' do; _by_module keeps the
# fleet's own (another fleet's names may begin alike: ``warehouse`` and ``warehouse-2``)
_PODS = 'namespace="{ns}",pod=~"{prefix}.*"'
MISSED = "sum by (module, pod) (increase(fogfleet_missed_cycles_total{{" + _PODS + "}}[{w}s]))"
CYCLES = "sum by (module, pod) (increase(fogfleet_cycle_time_seconds_count{{" + _PODS + "}}[{w}s]))"


@dataclass
class ObservedDeps:
    prometheus: SeriesPort
    period_seconds: float = 30.0


def drift_watch(
    fleet: RobotFleet, problem: Problem, catalog: Catalog, decision: Decision | None
) -> DriftWatch:
    """What drift detection needs of a fleet's full pass: its settings, the plan's predicted
    miss rate per module, one ComputeNode per hardware type (declared rows), the plan."""
    names = {n.name for n in problem.nodes}
    hardware = {
        nd.spec.hardware_type: nd for nd in catalog.nodes.values() if nd.metadata.name in names
    }
    if decision is None:
        return DriftWatch(fleet.spec.drift, {}, hardware, problem, None, "")
    predicted = module_miss_rates(problem, decision.placement, decision.schedule.with_limits)
    margin = float(fleet.spec.drift.margin_percent)
    budgets = {}
    for name in predicted:
        module = catalog.module(problem.namespace, name)
        budgets[name] = miss_budget(module.spec.taxonomy if module else None, margin)
    return DriftWatch(
        fleet.spec.drift,
        predicted,
        hardware,
        problem,
        decision.placement,
        decision.plan_id,
        budgets,
    )


def observe(deps: Deps, od: ObservedDeps, now: float) -> set[FleetKey]:
    """One round; the fleets whose measured state changed (to be reconciled)."""
    fleets = {
        s.key: (s, s.drift.watch)
        for s in deps.store.states()
        if s.drift.watch is not None and s.drift.watch.enabled
    }
    if not fleets:
        return set()
    watches = {key: watch for key, (_, watch) in fleets.items() if watch is not None}
    changed: set[FleetKey] = set()
    try:
        by_ns: dict[str, dict[str, list[Observation]]] = {}
        for ns in sorted({k[0] for k in fleets}):
            window = max(
                w.settings.window_seconds for k, w in watches.items() if k[0] == ns and w.settings
            )
            by_ns[ns] = read_observations(od.prometheus, ns, window)
            _write_observed(deps, ns, by_ns[ns], watches, now)
        for key, (state, watch) in fleets.items():
            assert watch is not None
            if _fleet_round(deps, od, state, watch, by_ns[key[0]], now):
                changed.add(key)
    except DependencyUnavailable as exc:
        log.warning("Reading the modules' measured cycles failed (last states stand): %s", exc)
    return changed


def read_observations(prometheus: SeriesPort, ns: str, window: int) -> dict[str, list[Observation]]:
    """Module -> its execution times per (hardware type, CPU limit) over the window, in
    namespace ``ns`` (the metrics contract's ``fogfleet_execution_time_seconds``)."""
    args = {"by": _BY, "ns": ns, "w": window}

    def by_key(promql: str) -> dict[tuple[str, str, str], float]:
        series = prometheus.query_series(promql, obj=f"namespace {ns}", field=FIELD)
        return {
            (m.get("module", ""), m.get("hardware_type", ""), m.get("cpu", "")): v
            for m, v in series
        }

    counts = by_key(EXEC_COUNT.format(**args))
    sums = by_key(EXEC_SUM.format(**args))
    p95s = by_key(EXEC_P95.format(**args))
    cycles = by_key(CYCLE_COUNT.format(**args))
    missed = by_key(CYCLE_MISSED.format(**args))
    out: dict[str, list[Observation]] = {}
    for (module, hw, cpu), n in sorted(counts.items()):
        if n < 1 or not module or not hw or (module, hw, cpu) not in sums:
            continue
        mean = sums[(module, hw, cpu)] / n
        out.setdefault(module, []).append(
            Observation(
                module,
                hw,
                parse_cpu(cpu) if cpu else None,
                n,
                mean,
                p95s.get((module, hw, cpu), mean),
                cycles.get((module, hw, cpu), 0.0),
                missed.get((module, hw, cpu), 0.0),
            )
        )
    return out


def _write_observed(
    deps: Deps,
    ns: str,
    observations: Mapping[str, list[Observation]],
    fleets: Mapping[FleetKey, DriftWatch],
    now: float,
) -> None:
    """status.observed of the namespace's modules that the fleets run and were measured."""
    hardware: dict[str, Any] = {}
    for key, watch in fleets.items():
        if key[0] == ns:
            hardware.update(watch.hardware)
    modules = {str(m["metadata"]["name"]): m for m in deps.kube.list_modules(ns)}
    for name, rows in sorted(observations.items()):
        raw = modules.get(name)
        if raw is None:
            continue
        declared = declared_rows(raw, hardware)
        entries = []
        for obs in rows:
            row = declared.get(obs.hardware_type)
            entry: Obj = {
                "hardwareType": obs.hardware_type,
                "cpu": "" if obs.cpu is None else f"{round(obs.cpu * 1000)}m",
                "count": round(obs.count, 1),
                "meanMillis": round(obs.mean * 1e3, 2),
                "stdMillis": round(obs.std * 1e3, 2),
                "p95Millis": round(obs.p95 * 1e3, 2),
                "lastUpdate": timestamp(now),
            }
            if obs.cycles >= 1:
                entry["cycles"] = round(obs.cycles, 1)
                entry["missedPercent"] = round(100 * obs.missed / obs.cycles, 2)
            if row is not None:
                got = declared_row(row, obs.cpu)
                if got is not None:
                    entry["declaredMeanMillis"] = round(got.mean * 1e3, 2)
            entries.append(entry)
        try:
            deps.kube.patch_module_status(ns, name, {"observed": entries})
        except FogfleetError as exc:
            log.warning("Writing SoftwareModule %s/%s status.observed failed: %s", ns, name, exc)


def declared_rows(raw: Mapping[str, Any], hardware: Mapping[str, Any]) -> dict[str, list[Any]]:
    """Hardware type -> the module's declared rows there (``hardware``: one ComputeNode per
    type, for the speed factor of 'default' rows)."""
    try:
        module = parse_object({k: v for k, v in raw.items() if k != "status"})
    except FogfleetError:
        return {}
    if not isinstance(module, SoftwareModule):
        return {}
    return {hw: profile_rows(module, node) for hw, node in hardware.items()}


def _fleet_round(
    deps: Deps,
    od: ObservedDeps,
    state: FleetState,
    watch: DriftWatch,
    observations: Mapping[str, list[Observation]],
    now: float,
) -> bool:
    key, settings, plan_id = state.key, watch.settings, watch.plan_id
    assert settings is not None
    epoch = state.drift.epoch
    before = state.drift.modules or {}
    if epoch is None or epoch[0] != plan_id:  # a new plan: its measures start now
        state.drift.epoch = epoch = (plan_id, now, epoch[2] if epoch else None)
        before = {}
    window = int(min(settings.window_seconds, now - epoch[1]))
    measured: dict[str, tuple[float, float]] = {}
    if window >= MIN_WINDOW_S:
        mine = _deployments(watch.problem)
        # Deployment names are DNS labels: no character a regex or a PromQL string reads
        args = {"ns": key[0], "prefix": _common_start(mine), "w": window}
        missed = _by_module(od, MISSED.format(**args), mine)
        cycles = _by_module(od, CYCLES.format(**args), mine)
        measured = {m: (missed.get(m, 0.0) / n, n) for m, n in cycles.items() if n >= 1}
    after: dict[str, ModuleDrift] = {}
    for module, predicted in sorted(watch.predicted.items()):
        rate, n = measured.get(module, (None, 0.0))
        prev = before.get(module)
        budget = watch.budgets.get(module) or miss_budget(None, float(settings.margin_percent))
        bad = drifting(predicted, rate, budget)
        since = (
            (prev.since if prev is not None and prev.since is not None else now) if bad else None
        )
        after[module] = ModuleDrift(predicted, rate, n, since, budget)
    due = [
        m
        for m, d in after.items()
        if drift_due(d.since, now, settings.for_seconds, epoch[2], settings.min_interval_seconds)
    ]
    if due and _adopt(deps, key, watch, due, after, observations, now):
        state.drift.epoch = (plan_id, epoch[1], now)
    state.drift.modules = after
    onboard_before, state.drift.onboard = state.drift.onboard, _onboard(watch, after, observations)
    return _summary(before) != _summary(after) or _shortfalls(onboard_before) != _shortfalls(
        state.drift.onboard
    )


def _onboard(
    watch: DriftWatch,
    states: Mapping[str, ModuleDrift],
    observations: Mapping[str, list[Observation]],
) -> dict[str, tuple[OnboardNeed, ...]]:
    """What each drifting module that cannot leave its robot needs there (domain.onboard):
    the re-plan cannot move it, so the fleet says whether its robots can give it that."""
    drifting = sorted(m for m, d in states.items() if d.since is not None)
    if not drifting or watch.placement is None:
        return {}
    used, _ = loads(watch.problem, watch.placement)  # the one per-node load model
    unreserved = watch.problem.capacity[:, 0] - used[:, 0]
    out = {}
    for module in drifting:
        needs = onboard_needs(
            watch.problem, watch.placement, module, observations.get(module, []), unreserved
        )
        if needs:
            out[module] = tuple(needs)
    return out


def _shortfalls(onboard: Mapping[str, tuple[OnboardNeed, ...]]) -> dict[str, int]:
    """What of the on-board needs the fleet's status shows: the worst need, in millicores."""
    return {m: round(needs[0].needed * 1000) for m, needs in onboard.items()}


def _summary(states: Mapping[str, ModuleDrift]) -> dict[str, tuple[Any, ...]]:
    """What of the states the fleet's status shows: whether each drifts and its rate to the
    two significant figures of MEASURED ("1.6%", "0.11%"). Coarser (whole points) left a rate
    that fell from 1.6 % to 0.11 % shown as 1.6 % for as long as it stayed there."""
    return {
        m: (d.since is not None, None if d.measured is None else float(f"{d.measured:.2g}"))
        for m, d in states.items()
    }


def _adopt(
    deps: Deps,
    key: FleetKey,
    watch: DriftWatch,
    modules: list[str],
    states: Mapping[str, ModuleDrift],
    observations: Mapping[str, list[Observation]],
    now: float,
) -> bool:
    """Write the corrections of the drifting ``modules`` (their watch events re-plan the
    fleets) and, since the fleet re-plans anyway, of its other measured modules: one drift
    re-plan per ``minIntervalSeconds`` learns all that was measured, not the first module to
    drift alone (a module missing a little less would wait out the interval)."""
    assert watch.settings is not None
    raws = {str(m["metadata"]["name"]): m for m in deps.kube.list_modules(key[0])}
    adopted = False
    others = [m for m in sorted(states) if m not in modules]
    for name in [*modules, *others]:
        if name not in modules and not adopted:
            break  # no drifting module was corrected: no re-plan, nothing else to learn
        raw = raws.get(name)
        obs = observations.get(name, [])
        if raw is None or not obs:
            continue
        timing = (
            timings(watch.problem, watch.placement, name) if watch.placement is not None else {}
        )
        declared = declared_rows(raw, watch.hardware)
        drift = watch.settings
        factors = correction(obs, declared, drift.prior_cycles, timing, drift.min_cycles)
        if not factors:
            continue
        d = states[name]
        why = (
            f"RobotFleet {key[1]} measured {name} missing {format_miss_rate(d.measured)} of its "
            f"cycles, predicted {format_miss_rate(d.predicted)}"
        )
        if name not in modules:
            why += f" (re-planned for the drift of {', '.join(modules)})"
        old = recorded_corrections(raw)
        for hw, (learnt, n) in factors.items():
            old[hw] = {
                "hardwareType": hw,
                "factor": round(learnt.factor, 4),
                "noiseMillis": round(learnt.noise * 1e3, 2),
                "noiseCycles": round(learnt.noise_cycles, 1),
                "samples": round(n, 1),
                "adoptedAt": timestamp(now),
                "reason": why,
            }
        entries = [old[hw] for hw in sorted(old)]
        try:
            deps.kube.patch_module_status(key[0], name, {"profileCorrection": entries})
        except FogfleetError as exc:
            log.warning(
                "Writing SoftwareModule %s/%s profileCorrection failed: %s", key[0], name, exc
            )
            continue
        text = ", ".join(describe(hw, got, n) for hw, (got, n) in factors.items())
        involved = {**raw, "apiVersion": f"{GROUP}/{VERSION}", "kind": "SoftwareModule"}
        deps.kube.emit_event(
            involved, "Warning", "ProfileCorrected", f"{why}: re-planned with its profile {text}"
        )
        log.info("SoftwareModule %s/%s: profile corrected (%s): %s", key[0], name, text, why)
        adopted = adopted or name in modules
    return adopted


def _deployments(problem: Problem) -> frozenset[str]:
    """Every Deployment a module of the fleet may run in: its instances' and their standbys'."""
    return frozenset(
        deployment_name(problem.fleet, inst, role)
        for inst in problem.instances
        for role in ("", ROLE_STANDBY)
    )


def _common_start(names: Collection[str]) -> str:
    """What every one of ``names`` begins with."""
    if not names:
        return ""
    first, last = min(names), max(names)
    same = (i for i, (a, b) in enumerate(zip(first, last, strict=False)) if a != b)
    return first[: next(same, min(len(first), len(last)))]


def _by_module(od: ObservedDeps, promql: str, deployments: Collection[str]) -> dict[str, float]:
    """Per module, the sum of the per-pod series of the pods of ``deployments``."""
    out: dict[str, float] = {}
    for labels, v in od.prometheus.query_series(promql, obj="drift", field="spec.drift"):
        if "module" in labels and pod_deployment(labels.get("pod", ""), deployments):
            out[labels["module"]] = out.get(labels["module"], 0.0) + v
    return out


def describe(hardware_type: str, learnt: Learnt, cycles: float) -> str:
    """One correction as the Events and the CLI say it."""
    noise = f" + {learnt.noise * 1e3:.1f} ms noise" if learnt.noise > 0 else ""
    return f"{hardware_type} x{learnt.factor:.2f}{noise} ({cycles:.0f} cycles)"
