"""What ``kubectl fogfleet`` computes, as plain documents (``plugin.output`` prints them as
tables, JSON or YAML): ``why``, ``top``, ``diff`` and ``plan --what-if``.

Every figure comes from the planner's code: ``scheduling.explain.alternatives`` for the reasons,
``objectives.module_miss_rates``/``objective_values`` for predictions, ``decision.decide``
(what the operator runs on a full pass, migration-margin rule included) for a re-plan."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from fogfleet.api.timestamps import parse_timestamp
from fogfleet.domain.problem import Problem
from fogfleet.errors import Infeasible
from fogfleet.scheduling.decision import CorePlanner, decide, fingerprint, with_defaults
from fogfleet.scheduling.objectives import REGISTRY, module_miss_rates, objective_values
from fogfleet.snapshot import room_note
from fogfleet.snapshot.live import Live

__all__ = ["diff_doc", "plan_doc", "top_doc"]

Doc = dict[str, Any]


def top_doc(live: Live, now: float | None = None) -> Doc:
    """Per fleet and per module: measured vs predicted miss rate, CPU requested by the plan
    and the CPU use it expects (measured CPU use is not in any status), the tier split, the
    fallbacks active (standbys computing on board while a robot's link is lost) and what the
    standbys did (``status.fallbacks[].takeovers``: the last takeover's gap, robot and age at
    ``now``, default the clock's)."""
    p, x, status = live.problem, live.placement, live.status
    now = time.time() if now is None else now
    took = _takeovers(status)
    alloc = p.allocation(live.with_limits)
    placed = x >= 0
    rows = np.flatnonzero(placed)
    request = np.zeros(p.n_instances)
    request[rows] = alloc.cpu_request[rows, x[rows]]
    expected = np.zeros(p.n_instances)
    expected[rows] = p.activation[rows] * alloc.cpu_use[rows, x[rows]]
    predicted = module_miss_rates(p, x, live.with_limits)
    active = {
        str(link.get("robot")): list(link.get("standbysActive") or [])
        for link in status.get("links") or []
        if link.get("standbysActive")
    }
    modules: list[Doc] = []
    for name in p.module_names:
        idx = np.array([i for i, inst in enumerate(p.instances) if inst.module == name])
        modules.append(
            {
                "module": name,
                "instances": int(placed[idx].sum()),
                "split": _split(p, x[idx]),
                "predictedMissRate": predicted.get(name),
                "measuredMissRate": live.measured.get(name),
                "cpuRequested": round(float(request[idx].sum()), 3),
                "cpuExpected": round(float(expected[idx].sum()), 3),
                "moduleSplit": live.snapshot.module_splits.get(name),
                "fallbacksActive": sorted(r for r, mods in active.items() if name in mods),
                "takeovers": took.get(name, []),
                "lastTakeover": _last_takeover(took.get(name, []), now),
            }
        )
    rates = [float(m["measuredMissRate"]) for m in modules if m["measuredMissRate"] is not None]
    measured = status.get("measuredMissRate")
    return {
        "fleet": f"{p.namespace}/{p.fleet}",
        "predictedMissRate": status.get("predictedMissRate"),
        # the operator's cycle-weighted rate; without it (an older operator) the modules' mean
        "measuredMissRate": measured
        if measured is not None
        else (sum(rates) / len(rates) if rates else None),
        "takeovers": sum(t["count"] for ts in took.values() for t in ts) if took else None,
        "split": status.get("split") or _split(p, x),
        "cpuRequested": round(float(request.sum()), 3),
        "cpuExpected": round(float(expected.sum()), 3),
        "fallbacksActive": {r: sorted(m) for r, m in sorted(active.items())},
        "modules": modules,
    }


def _takeovers(status: Mapping[str, Any]) -> dict[str, list[Doc]]:
    """Module -> per robot, what its standby did (``status.fallbacks[].takeovers``)."""
    out: dict[str, list[Doc]] = {}
    for f in status.get("fallbacks") or []:
        for t in f.get("takeovers") or []:
            out.setdefault(str(t["module"]), []).append(
                {
                    "robot": str(f.get("robot")),
                    "count": int(t.get("count") or 0),
                    "lastGapSeconds": t.get("lastGapSeconds"),
                    "lastTakeoverTime": t.get("lastTakeoverTime"),
                    "active": bool(t.get("active")),
                }
            )
    return out


def _last_takeover(takeovers: list[Doc], now: float) -> Doc | None:
    """The module's newest takeover on any robot, with its age in seconds (None: none)."""
    seen = [
        (at, t)
        for t in takeovers
        if t["count"] and (at := parse_timestamp(t["lastTakeoverTime"])) is not None
    ]
    if not seen:
        return None
    at, t = max(seen, key=lambda pair: pair[0])
    return {
        "robot": t["robot"],
        "gapSeconds": t["lastGapSeconds"],
        "time": t["lastTakeoverTime"],
        "agoSeconds": max(0, round(now - at)),
    }


def diff_doc(live: Live) -> Doc:
    """The plan a full re-plan would deploy now against the running one."""
    return plan_doc(live, live)


def plan_doc(live: Live, running: Live) -> Doc:
    """Plan ``live`` (perhaps a what-if of ``running``) as the operator would, apply nothing,
    and compare with the placement that runs: the moves and each objective's change."""
    p = live.problem
    fleet = live.fleet
    settings = with_defaults(fleet.spec.scheduler, {})
    before = _before(p, running)
    try:
        decision = decide(
            CorePlanner(),
            p,
            settings,
            fleet=fleet.metadata.name,
            fp=fingerprint(p, settings),
            before=before,
        )
    except Infeasible as err:  # on nodes others hold part of: say who, in cores
        room = room_note(p, live.snapshot.held)
        raise (Infeasible(err.obj, err.field, f"{err.message}; {room}") if room else err) from None
    planned = p.with_levels(decision.schedule.levels)
    names = list(REGISTRY)
    after = objective_values(planned, decision.placement, live.with_limits, names)
    known = before >= 0
    now = (
        objective_values(p, before, live.with_limits, names)
        if bool(known.all())
        else dict.fromkeys(names, float("nan"))
    )
    moves = [
        {
            "instance": p.label(i),
            "from": p.nodes[int(before[i])].name if before[i] >= 0 else None,
            "to": p.nodes[int(decision.placement[i])].name,
        }
        for i in range(p.n_instances)
        if decision.placement[i] >= 0 and decision.placement[i] != before[i]
    ]
    return {
        "fleet": f"{p.namespace}/{p.fleet}",
        "applied": False,
        "choiceReason": decision.choice_reason,
        "moves": moves,
        "objectives": [
            {"name": n, "running": now[n], "planned": after[n], "change": after[n] - now[n]}
            for n in names
        ],
        "predictedMissRate": module_miss_rates(planned, decision.placement, live.with_limits),
    }


def _before(p: Problem, running: Live) -> np.ndarray:
    """The running placement on ``p``'s instances (a what-if may add some: -1 for those)."""
    index: Mapping[tuple[str, str, int], int] = {
        (inst.robot, inst.module, inst.replica): int(running.placement[i])
        for i, inst in enumerate(running.problem.instances)
    }
    names = {nd.name: j for j, nd in enumerate(p.nodes)}
    out = np.full(p.n_instances, -1, dtype=np.int64)
    for i, inst in enumerate(p.instances):
        j = index.get((inst.robot, inst.module, inst.replica), -1)
        if j >= 0:
            out[i] = names.get(running.problem.nodes[j].name, -1)
    return out


def _split(p: Problem, x: np.ndarray) -> str:
    """Instances on robots/edge/cloud, as status writes it ("3/2/0")."""
    placed = x[x >= 0]
    counts = np.bincount(p.tier[placed], minlength=3) if placed.size else np.zeros(3, int)
    return "/".join(str(int(c)) for c in counts[:3])
