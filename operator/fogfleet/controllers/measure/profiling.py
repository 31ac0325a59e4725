"""Profiling Jobs: start them, read what they measured, record the fitted profile (issue 10).

A fleet reconcile calls :func:`advance_profiling` with the profiles its modules lack
(``domain.profiling.needed_profiles``). Per (module, hardware type) it creates the Jobs of the
grid's edge cases that do not exist yet (idempotent: a Job's name is its run's), reads each
finished Job's termination message, and once every Job succeeded fits the profile, writes
``status.profiling`` of the SoftwareModule (the runs and the rows), posts a ``Profiled``
Event and deletes the Jobs. A Job that failed fails the run (``ProfilingFailed``, with the
pod's own words): the fleet waits, and a change to the module's container or profiling
settings profiles it again. Until then the fleet is told what it waits for.

A split network (``spec.dnn``) gets one Job per hardware type, which times every part of its
network (``contract.dnn``); what it measured goes to ``status.profiling.dnn``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fogfleet import API_VERSION
from fogfleet.api.labels import LABEL_PROFILE_CPU
from fogfleet.api.loader import Catalog
from fogfleet.api.timestamps import timestamp
from fogfleet.api.v1alpha1.base import format_millicores, parse_cpu
from fogfleet.api.v1alpha1.common import Tier
from fogfleet.api.v1alpha1.computenode import ComputeNode
from fogfleet.api.v1alpha1.dnn import DnnHardwareProfile
from fogfleet.api.v1alpha1.profiling import ProfiledRow, ProfilingRun, ProfilingStatus
from fogfleet.api.v1alpha1.robotfleet import RobotFleet
from fogfleet.api.v1alpha1.softwaremodule import SoftwareModule
from fogfleet.contract.dnn import RESULT_KEY
from fogfleet.controllers.deps import Deps
from fogfleet.domain.profiling import (
    Measurement,
    dnn_limit,
    edge_cases,
    fit_profile,
    grid_for,
    module_spec_hash,
    needed_profiles,
    profiling_status,
)
from fogfleet.domain.references import resolve_nodes
from fogfleet.errors import FogfleetError
from fogfleet.render.profiling import profiling_selector, render_profiling_job
from fogfleet.snapshot.objects import profiling_record

__all__ = [
    "PROFILING_POLL_SECONDS",
    "Waiting",
    "advance_profiling",
    "profile_first",
]

PROFILING_POLL_SECONDS = 5.0  # a fleet waiting for Jobs looks again this often

log = logging.getLogger(__name__)
Obj = dict[str, Any]
Found = list[ProfiledRow] | DnnHardwareProfile  # what a finished run adds to the status


@dataclass
class Waiting:
    """What a fleet waits for: one line per (module, hardware type) not profiled yet."""

    lines: list[str] = field(default_factory=list)
    failed: bool = False  # a run failed: the fleet waits for the user, not for a Job

    def __bool__(self) -> bool:
        return bool(self.lines)

    @property
    def message(self) -> str:
        return "waiting for profiles: " + "; ".join(self.lines)


def profile_first(
    deps: Deps, fleet: RobotFleet, catalog: Catalog, raw_modules: Sequence[Obj]
) -> tuple[Waiting, bool]:
    """Advance the profiling the fleet's modules need on its nodes; returns what it still waits
    for and whether a profile was recorded now (the caller then reads the modules again)."""
    ns = fleet.metadata.namespace or "default"
    modules = [catalog.module(ns, ref.name) for ref in fleet.spec.modules]
    robots, others = resolve_nodes(fleet, catalog)
    needs = needed_profiles((m for m in modules if m is not None), robots + others)
    if not needs:
        return Waiting(), False
    by_name = {m.metadata.name: m for m in modules if m is not None}
    raw = {r["metadata"]["name"]: r for r in raw_modules if r["metadata"]["name"] in needs}
    before = {n: profiling_record(r) for n, r in raw.items()}
    waiting = advance_profiling(deps, needs, by_name, raw)
    recorded = any(profiling_record(r) != before[n] for n, r in raw.items())
    return waiting, recorded and not waiting


def advance_profiling(
    deps: Deps,
    needs: Mapping[str, Mapping[str, Sequence[ComputeNode]]],
    modules: Mapping[str, SoftwareModule],
    raw_modules: Mapping[str, Obj],
) -> Waiting:
    """Move every needed profiling one step (see the module docstring); ``raw_modules`` (by
    name) get the status written, so the caller can plan with it in the same pass."""
    waiting = Waiting()
    for name, by_type in sorted(needs.items()):
        module, raw = modules[name], raw_modules[name]
        status = profiling_status(raw) or ProfilingStatus()
        spec_hash = module_spec_hash(module)
        runs = {r.hardware_type: r for r in status.runs}
        changed = False
        for hw, nodes in sorted(by_type.items()):
            run = runs.get(hw)
            if run is not None and run.spec_hash == spec_hash and run.state == "Failed":
                waiting.lines.append(f"{name} on {hw}: profiling failed: {run.message}")
                waiting.failed = True
                continue
            new_run, found = _step(deps, module, raw, hw, nodes, spec_hash, run)
            if new_run is not None and new_run != run:
                runs[hw] = new_run
                changed = True
                if found is not None:
                    status = _with_found(status, hw, found)
            if new_run is None or new_run.state != "Profiled":
                run_now = runs.get(hw)
                waiting.lines.append(
                    f"{name} on {hw}: {run_now.message if run_now else 'starting'}"
                )
                waiting.failed = waiting.failed or (
                    run_now is not None and run_now.state == "Failed"
                )
        if changed:
            status = status.model_copy(update={"runs": [runs[k] for k in sorted(runs)]})
            wire = status.wire()
            ns = module.metadata.namespace or "default"
            try:
                deps.kube.patch_module_status(ns, name, {"profiling": wire})
            except FogfleetError as exc:
                log.warning("Writing SoftwareModule %s/%s profiling failed: %s", ns, name, exc)
                waiting.lines.append(f"{name}: its status could not be written ({exc})")
                continue
            raw.setdefault("status", {})["profiling"] = wire
    return waiting


def _with_found(status: ProfilingStatus, hw: str, found: Found) -> ProfilingStatus:
    """``status`` with what the run on ``hw`` found in place of what an earlier run found."""
    if isinstance(found, DnnHardwareProfile):
        kept = [p for p in status.dnn if p.hardware_type != hw]
        return status.model_copy(update={"dnn": [*kept, found]})
    keep = [r for r in status.rows if r.hardware_type != hw]
    return status.model_copy(update={"rows": [*keep, *found]})


def _limits(module: SoftwareModule, nodes: Sequence[ComputeNode]) -> tuple[list[float], str]:
    """The module's grid on these nodes and why it is empty (a split network: its one
    limit, ``dnn_limit``)."""
    usable = [_usable_cpu(n) for n in nodes]
    most = format_millicores(max(usable, default=0.0))
    if module.spec.dnn is not None:
        limit = dnn_limit(usable)
        return ([limit] if limit > 0 else []), f"a {nodes[0].spec.hardware_type} node has no CPU"
    why = f"no CPU limit of spec.profiling.cpus fits a {nodes[0].spec.hardware_type} node"
    return grid_for(module, usable), f"{why} (the largest can give {most})"


def _step(
    deps: Deps,
    module: SoftwareModule,
    raw: Obj,
    hw: str,
    nodes: Sequence[ComputeNode],
    spec_hash: str,
    run: ProfilingRun | None,
) -> tuple[ProfilingRun | None, Found | None]:
    """One (module, hardware type): the run as it stands now and, once profiled, what it
    found (the rows, or a split network's profile)."""
    name = module.metadata.name
    ns = module.metadata.namespace or "default"
    grid, empty = _limits(module, nodes)
    now = timestamp()
    if not grid:
        return _failed(deps, raw, hw, spec_hash, grid, empty, now, run), None
    limits = edge_cases(grid)
    split = module.spec.dnn is not None
    jobs = {
        j["metadata"]["labels"].get(LABEL_PROFILE_CPU): j
        for j in deps.kube.list_jobs(ns, profiling_selector(name, hw, spec_hash))
    }
    robots = all(n.spec.tier is Tier.ROBOT for n in nodes)
    node_names = sorted({n.node_name for n in nodes})
    measured: list[Measurement] = []
    profiles: list[DnnHardwareProfile] = []
    pending = 0
    for cpu in limits:
        label = format_millicores(cpu)
        job = jobs.get(label)
        if job is None:
            body = render_profiling_job(
                module,
                hardware_type=hw,
                cpu=cpu,
                node_names=node_names,
                robots=robots,
                spec_hash=spec_hash,
            )
            deps.kube.create_job(body)
            log.info(
                "Started profiling Job %s/%s: %s on %s at %s",
                ns,
                body["metadata"]["name"],
                name,
                hw,
                label,
            )
            pending += 1
            continue
        result = _result(deps, ns, job, cpu, hw if split else None)
        if isinstance(result, str):
            why = f"Job {job['metadata']['name']} ({label}) failed: {result}"
            return _failed(deps, raw, hw, spec_hash, grid, why, now, run), None
        if result is None:
            pending += 1
        else:
            measured.append(result[0])
            profiles += [result[1]] if result[1] is not None else []
    if pending:
        done = len(limits) - pending
        message = f"{done} of {len(limits)} profiling Jobs done"
        if run is not None and run.state == "Running" and run.message == message:
            return run, None
        return (
            ProfilingRun(
                hardware_type=hw,
                state="Running",
                jobs=len(limits),
                grid=len(grid),
                message=message,
                spec_hash=spec_hash,
                last_update=now,
            ),
            None,
        )
    cpu_s = sum(m.cpu_seconds for m in measured)
    wall_s = sum(m.wall_seconds for m in measured)
    found: Found
    if profiles:
        fit, found = None, profiles[0]
        message = (
            f"1 Job at {format_millicores(limits[0])} timed every part over {found.frames} "
            f"frames ({cpu_s:.1f} CPU-s): the whole network {found.full_millis:g} ms, the "
            f"local model {found.local_millis:g} ms per frame"
        )
    else:
        fit = fit_profile(hw, grid, measured)
        found = list(fit.rows)
        message = (
            f"{len(limits)} Jobs at {', '.join(format_millicores(c) for c in limits)} "
            f"({cpu_s:.1f} CPU-s) instead of {len(grid)}"
            + (
                f"; the middle limit predicted from the ends {fit.error_percent:g} % off"
                if fit.error_percent is not None
                else ""
            )
        )
    new_run = ProfilingRun(
        hardware_type=hw,
        state="Profiled",
        jobs=len(limits),
        grid=len(grid),
        cpu_seconds=round(cpu_s, 3),
        wall_seconds=round(wall_s, 3),
        fit_error_percent=None if fit is None else fit.error_percent,
        message=message,
        spec_hash=spec_hash,
        last_update=now,
    )
    deps.kube.emit_event(_about(raw), "Normal", "Profiled", f"Profiled on {hw}: {message}")
    log.info("Profiled SoftwareModule %s/%s on %s: %s", ns, name, hw, message)
    for job in jobs.values():
        deps.kube.delete_job(ns, job["metadata"]["name"])
    return new_run, found


def _failed(
    deps: Deps,
    raw: Obj,
    hw: str,
    spec_hash: str,
    grid: Sequence[float],
    why: str,
    now: str,
    run: ProfilingRun | None,
) -> ProfilingRun:
    if run is not None and run.state == "Failed" and run.spec_hash == spec_hash:
        return run
    deps.kube.emit_event(
        _about(raw), "Warning", "ProfilingFailed", f"Profiling on {hw} failed: {why}"
    )
    return ProfilingRun(
        hardware_type=hw,
        state="Failed",
        jobs=run.jobs if run else 0,
        grid=len(grid),
        message=why,
        spec_hash=spec_hash,
        last_update=now,
    )


def _about(raw: Obj) -> Obj:
    """An Event's object: a listed SoftwareModule lacks its kind and apiVersion."""
    return {**raw, "apiVersion": API_VERSION, "kind": "SoftwareModule"}


def _usable_cpu(node: ComputeNode) -> float:
    """CPU a Job may get on ``node``: its capacity less what it keeps reserved."""
    cap = parse_cpu(node.spec.capacity.cpu) if node.spec.capacity else 0.0
    kept = parse_cpu(node.spec.reserved.cpu) if node.spec.reserved else 0.0
    return max(0.0, cap - kept)


Measured = tuple[Measurement, DnnHardwareProfile | None]


def _result(
    deps: Deps, ns: str, job: Obj, cpu: float, split_hw: str | None
) -> Measured | str | None:
    """What a Job measured (with a split network's profile on ``split_hw``), why it failed
    (str), or None while it runs."""
    status = job.get("status") or {}
    name = job["metadata"]["name"]
    failed = next(
        (
            c
            for c in status.get("conditions") or []
            if c.get("type") == "Failed" and c.get("status") == "True"
        ),
        None,
    )
    if not status.get("succeeded") and failed is None:
        return None
    pods = deps.kube.list_job_pods(ns, name)
    terminated = [
        ((cs.get("state") or {}).get("terminated") or {})
        for p in pods
        for cs in (p.get("status") or {}).get("containerStatuses") or []
    ]
    if failed is not None:
        said = [t.get("message", "").strip() or t.get("reason", "") for t in terminated if t]
        detail = "; ".join(s for s in said if s)[-300:]
        return f"{failed.get('reason', 'Failed')}: {detail or failed.get('message', '')}"
    for t in terminated:
        if t.get("exitCode") == 0 and t.get("message"):
            got = _measurement(t["message"], cpu, split_hw)
            return got or "its termination message is not a profile"
    return "it succeeded without a termination message (the profiling contract)"


def _measurement(text: str, cpu: float, split_hw: str | None) -> Measured | None:
    """A Job's result line (``workload.profile``; a split network's also carries its parts'
    times under ``contract.dnn.RESULT_KEY``), None when it is not one."""
    try:
        data = json.loads(text.strip().splitlines()[-1])
        measured = Measurement(
            cpu=cpu,
            mean_ms=float(data["meanMillis"]),
            std_ms=float(data["stdMillis"]),
            cycles=int(data["cycles"]),
            cpu_seconds=float(data.get("cpuSeconds", 0.0)),
            wall_seconds=float(data.get("wallSeconds", 0.0)),
        )
        if split_hw is None:
            return measured, None
        parts = dict(data[RESULT_KEY], hardwareType=split_hw, frames=measured.cycles)
        return measured, DnnHardwareProfile.model_validate(parts)
    except (ValueError, KeyError, TypeError, IndexError):
        return None
