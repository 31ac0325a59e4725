"""Why a module's instances run where they run (``fogfleet explain``, ``kubectl fogfleet why``).

For each instance, every node it could have used and why the plan did not use it, from the
planner's own answers only:

- a node outside its gene space: the refusal ``domain.pairs.PairTable.pair`` gave the build
  (the taxonomy, a tier, a device, a GPU, the real-time kernel, privacy, the profile), passed
  in as ``refused`` (``domain.build.refusals``), or the node being unavailable;
- a node inside it: the plan with that one instance moved there, scored by the local search's
  incremental move evaluation (``local.MoveEvaluator``: the same values as
  ``objectives.evaluate`` of the moved plan): a capacity or uplink constraint it would break,
  with the amounts (``Fit.demand_at`` against the node's requests in ``Evaluation``), else
  "allowed, but worse on <objective> by <amount>" with every objective's change.

Moves are scored incrementally (one pass over the nodes per move), so a 1000-robot fleet is
explained in well under a second (``fogfleet bench why``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from fogfleet.api.v1alpha1.base import format_cores
from fogfleet.domain.dnnpairs import planned_choice
from fogfleet.domain.problem import Problem
from fogfleet.domain.tenancy import Held
from fogfleet.errors import InvalidSpec
from fogfleet.scheduling.evaluation import UPLINK_SHARE
from fogfleet.scheduling.local import MoveEvaluator
from fogfleet.scheduling.objectives import (
    EVALUATORS,
    REGISTRY,
    Evaluation,
    constraint_names,
    module_miss_rates,
)
from fogfleet.scheduling.problem import RESOLUTION, PlacementProblem

__all__ = ["Alternative", "InstanceWhy", "ModuleWhy", "explain_module", "instances_of"]

I64 = NDArray[np.int64]
Refused = Callable[[int], Mapping[int, str | None]]
EPS = 1e-9


@dataclass(frozen=True)
class Alternative:
    """One node an instance could have used, and why the plan did not."""

    node: str
    tier: str
    rule: str  # a refusal's rule, "unavailable", "capacity", "uplink" or "objectives"
    reason: str
    deltas: dict[str, float] = field(default_factory=dict)  # objective -> moved minus plan


@dataclass(frozen=True)
class InstanceWhy:
    """Where one instance runs, its predicted miss probability, and its alternatives."""

    label: str
    robot: str
    replica: int
    node: str | None
    tier: str | None
    cpu: float | None  # its CPU request there, cores
    predicted_miss: float
    alternatives: tuple[Alternative, ...]
    # a split network's: the action taken with its tail here and why, then each other action
    # and why not (contract.dnnsplit.choose); None: not a split network
    split: tuple[str, str, tuple[tuple[str, str], ...]] | None = None


@dataclass(frozen=True)
class ModuleWhy:
    """A module's instances explained, with the plan's objective values."""

    fleet: str
    module: str
    objectives: tuple[str, ...]  # the fleet's, in its order (the ones "worse on" names)
    values: dict[str, float]  # every objective of the plan
    predicted_miss_rate: float | None
    instances: tuple[InstanceWhy, ...]
    omitted: int = 0  # instances not explained (beyond ``limit``)
    measured_miss_rate: float | None = None  # filled in by a caller that measured it


def instances_of(problem: Problem, module: str, robot: str | None = None) -> list[int]:
    """The instances of ``module`` (of ``robot`` only, when given)."""
    return [
        i
        for i, inst in enumerate(problem.instances)
        if inst.module == module and (robot is None or inst.robot == robot)
    ]


def explain_module(
    problem: Problem,
    placement: I64,
    with_limits: bool,
    module: str,
    *,
    robot: str | None = None,
    objectives: Sequence[str] = tuple(REGISTRY),
    refused: Refused | None = None,
    unavailable: Mapping[int, str] | None = None,
    held: Mapping[str, Held] | None = None,
    limit: int = 50,
) -> ModuleWhy:
    """Explain the instances of ``module`` (of ``robot``) in the plan ``placement`` (I,).

    ``refused(i)`` gives instance i's refusals by node (``domain.build.refusals``; None: not a
    node it could use); ``unavailable`` the nodes masked out and why; ``held`` what other
    fleets and pods hold on each Kubernetes node (a node too full names them). At most ``limit``
    instances are explained (the rest are counted in ``omitted``)."""
    chosen = instances_of(problem, module, robot)
    if not chosen:
        who = f" of robot {robot}" if robot else ""
        raise InvalidSpec(
            f"RobotFleet/{problem.fleet}", "", f"has no instance of module {module}{who}"
        )
    shown = chosen[:limit]
    x = np.asarray(placement, dtype=np.int64)
    # the search's view narrowed to the moves asked about: only the shown instances are genes
    # (the objectives never read gene spaces, and only the node columns of G are read), so
    # the evaluator's tables hold their pairs, not every (instance, node) pair of the fleet
    narrow = np.zeros_like(problem.allowed)
    narrow[shown] = problem.allowed[shown]
    pp = PlacementProblem(
        replace(problem, allowed=narrow), list(EVALUATORS), with_limits=with_limits
    )
    me = MoveEvaluator(pp)
    ev = me.parents(x[None, :])
    base = {n: float(EVALUATORS[n](ev)[0]) for n in EVALUATORS}
    miss = ev.instance_miss()[0]
    # every move of every shown instance to another node of its gene space, scored at once
    moves = [
        (i, int(j))
        for i in shown
        if x[i] >= 0
        for j in np.flatnonzero(problem.allowed[i])
        if j != x[i]
    ]
    scored: dict[tuple[int, int], Alternative] = {}
    if moves:
        inst = np.array([m[0] for m in moves], dtype=np.int64)
        node = np.array([m[1] for m in moves], dtype=np.int64)
        vals, G = me.evaluate(x[None, :], np.zeros(len(moves), dtype=np.int64), inst, node, ev)
        g0 = ev.constraints()[0]
        names = constraint_names(problem)
        for k, (i, j) in enumerate(moves):
            deltas = {n: float(vals[n][k]) - base[n] for n in EVALUATORS}
            broken = [c for c in np.flatnonzero(G[k, :-1] > np.maximum(g0[:-1], 0.0) + EPS)]
            if broken:
                rule, why = _constraint(problem, pp, ev, i, j, names[int(broken[0])], held or {})
            else:
                rule, why = "objectives", _trade(deltas, objectives)
            nd = problem.nodes[j]
            scored[i, j] = Alternative(nd.name, nd.tier.value, rule, why, deltas)
    alloc = problem.allocation(with_limits)
    order = {nd.name: j for j, nd in enumerate(problem.nodes)}
    out = []
    for i in shown:
        inst_ = problem.instances[i]
        here = int(x[i])
        alts = _refusals(problem, i, here, refused, unavailable or {})
        alts += [
            scored[i, int(j)] for j in np.flatnonzero(problem.allowed[i]) if (i, int(j)) in scored
        ]
        alts.sort(key=lambda a: order[a.node])
        out.append(
            InstanceWhy(
                label=problem.label(i),
                robot=inst_.robot,
                replica=inst_.replica,
                node=problem.nodes[here].name if here >= 0 else None,
                tier=problem.nodes[here].tier.value if here >= 0 else None,
                cpu=float(alloc.cpu_request[i, here]) if here >= 0 else None,
                predicted_miss=float(miss[i]),
                alternatives=tuple(alts),
                split=_split(problem, i, here),
            )
        )
    return ModuleWhy(
        fleet=f"{problem.namespace}/{problem.fleet}",
        module=module,
        objectives=tuple(objectives),
        values=base,
        predicted_miss_rate=module_miss_rates(problem, x, with_limits).get(module),
        instances=tuple(out),
        omitted=len(chosen) - len(shown),
    )


def _split(
    problem: Problem, i: int, here: int
) -> tuple[str, str, tuple[tuple[str, str], ...]] | None:
    """A split network's action on its node, why, and why not each other action."""
    got = planned_choice(problem, i, here) if here >= 0 else None
    if got is None:
        return None
    return got.action.name, got.reason, tuple((a.name, why) for a, why in got.dropped)


def _refusals(
    problem: Problem, i: int, here: int, refused: Refused | None, unavailable: Mapping[int, str]
) -> list[Alternative]:
    """The nodes outside instance i's gene space that it could otherwise use, and why."""
    said = refused(i) if refused is not None else {}
    out = []
    for col in np.flatnonzero(~problem.allowed[i]):
        j = int(col)
        if j == here:
            continue
        nd = problem.nodes[j]
        if j in unavailable:
            rule, why = "unavailable", f"{nd.name}: node is {unavailable[j]}"
        elif j in said:
            text = said[j]
            if text is None:
                continue  # not a node it could use: another robot's computer, another pool
            rule, why = getattr(text, "rule", "requirement"), str(text)
        else:
            continue  # the build allowed it; only a mask (unavailable) took it out
        out.append(Alternative(nd.name, nd.tier.value, rule, why.partition(": ")[2] or why))
    return out


def _constraint(
    problem: Problem,
    pp: PlacementProblem,
    ev: Evaluation,
    i: int,
    j: int,
    column: str,
    held: Mapping[str, Held],
) -> tuple[str, str]:
    """The constraint the move of instance i to node j would break, with the amounts; on a
    node others hold CPU of, who holds how much (the room the fleet was planned into)."""
    what, _, name = column.partition(":")
    k = problem.node_index(name)
    need = pp.fit.demand_at(np.array([i]), np.array([j]))[0]
    cap = problem.capacity[k]
    if what == "uplink":
        used = float(ev.offboard_traffic[0, k])
        limit = UPLINK_SHARE * float(problem.uplink_bandwidth[k])
        return "uplink", (
            f"{name}'s uplink would carry {(used + problem.traffic[i]) / 1e6:.1f} Mbit/s, over "
            f"its limit of {limit / 1e6:.1f} Mbit/s ({UPLINK_SHARE:.0%} of the link)"
        )
    r = {"cpu": 0, "memory": 1, "gpu": 2}[what]
    used = float((ev.cpu_requested, ev.mem_requested, ev.gpu_requested)[r][0, k])
    free = max(float(cap[r]) - used, 0.0)
    others = held.get(problem.nodes[k].node_name, Held())
    shared = (
        f"; other fleets and pods hold {_amount('cpu', others.cpu)} more there "
        f"({others.itemised()})"
        if what == "cpu" and others.cpu > 0
        else ""
    )
    return "capacity", (
        f"needs {_amount(what, float(need[r]))} {what} but {name} has "
        f"{_amount(what, free)} of {_amount(what, float(cap[r]))} free{shared}"
    )


def _trade(deltas: Mapping[str, float], objectives: Sequence[str]) -> str:
    """ "allowed, but worse on <objective> by <amount>" over the fleet's objectives."""
    worse = [(n, d) for n, d in deltas.items() if n in objectives and d > RESOLUTION.get(n, EPS)]
    better = [(n, d) for n, d in deltas.items() if n in objectives and d < -RESOLUTION.get(n, EPS)]
    if worse:
        said = ", ".join(f"{n} by {_signed(d)}" for n, d in worse)
        also = f" (better on {', '.join(n for n, _ in better)})" if better else ""
        return f"allowed, but worse on {said}{also}"
    if better:
        said = ", ".join(f"{n} by {_signed(d)}" for n, d in better)
        return f"allowed, and better on {said}: kept where it runs (migration margin)"
    return "allowed, and as good on every objective: the plan's choice among equals"


def _signed(value: float) -> str:
    return f"{value:+.4g}"


def _amount(resource: str, value: float) -> str:
    if resource == "memory":
        return f"{value / 2**30:.2f}Gi"
    if resource == "cpu":
        return format_cores(value)
    return f"{value:g}"
