"""``plan``: one entry point for every scheduler of RobotFleet.spec.scheduler.algorithm."""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from pymoo.operators.selection.tournament import TournamentSelection

from fogfleet.api.v1alpha1.base import parse_millis, parse_quantity
from fogfleet.api.v1alpha1.objectives import MISS_OBJECTIVES
from fogfleet.api.v1alpha1.robotfleet import SchedulerName, SchedulerSettings
from fogfleet.domain.problem import Problem

from .baselines import finish, k8s_default, onboard_plan, random_plan
from .bookkeeping import (
    ArrayEvaluator,
    FleetNSGA2,
    GeneDuplicates,
    RankAndCrowdingSurvival,
    binary_tournament,
)
from .choice import choose, non_dominated
from .configurations import with_priced
from .convergence import WARM_GENERATIONS, StallWatch, stall_window
from .degrade import degrade, short_of_cpu
from .exact import describe_weights, fleet_weights, scalarised, solve_exact
from .levelling import with_levelled
from .local import pareto_local_search
from .mating import ArrayMating
from .operators import (
    CapacityRepair,
    FleetSampling,
    GeneCrossover,
    GeneMutation,
)
from .preference import polish, tie_breakers
from .problem import PlacementProblem
from .schedule import Budget, Clock, Schedule
from .spread import spread_note, spread_plans, stacked

ENUMERATE_LIMIT = 20_000  # plans; smaller search spaces are enumerated exactly
# The stages' shares of spec.scheduler.timeBudgetMillis: each stops once the clock passes its
# share (``Budget``), so the whole search ends within the budget. The levelling, the local
# search and the polish are bounded by work too, and on a fleet whose search ends within the
# budget the plan depends only on the inputs and the seed. At 1000 robots the stages after the
# evolution took ~40 % of the plan (levelling 3.2 s, local search 0.9 s, polish 1.0 s of 14 s).
EVOLUTION_SHARE = 0.6
LOCAL_SEARCH_SHARE = 0.9  # the priced plans, the levelling and the local search
# the priced plans' seconds per allowed (instance, node) pair: at 1000 robots (2.4 M pairs)
# the bound and the packing took 2-2.8 s on a 2-core machine, asked whether to stop only
# between steps of up to ~1.2 s, so they start only where this much of the budget is left
PRICED_SECONDS_PER_PAIR = 1e-6
POLISH_SHARE = 0.97
OVER_BUDGET = 1.1  # a search past this multiple of its budget says why in its reason

__all__ = [
    "Clock",
    "Progress",
    "choose_plan",
    "every_choice",
    "exact_weights",
    "nsga2",
    "plan",
    "weights_of",
]

Progress = Callable[[int, int], None]
I64 = NDArray[np.int64]


class Stop(enum.Enum):
    """Why the evolution ended."""

    GENERATIONS = "generations"  # all of spec.scheduler.generations ran
    BUDGET = "budget"  # the time budget cut it
    STALLED = "stalled"  # converged: convergence.StallWatch
    WARM = "warm"  # a warm start's generations ran: convergence.WARM_GENERATIONS
    EXHAUSTIVE = "exhaustive"  # a small search space was enumerated instead


def exact_weights(problem: Problem, settings: SchedulerSettings) -> dict[str, float]:
    """The weights of S the exact scheduler minimises for a fleet with ``settings``
    (``exact.fleet_weights``): its MILP, and the gap ``scheduling.gap`` reports."""
    return fleet_weights(problem, [str(n) for n in settings.objectives], weights_of(settings))


def weights_of(settings: SchedulerSettings) -> dict[str, float]:
    """The weighted choice's weights by objective; a weight is a number or a quantity
    ("500m" = 0.5), as the CRD accepts it."""
    return {w.objective.value: parse_quantity(w.weight) for w in settings.weights}


def plan(
    problem: Problem,
    settings: SchedulerSettings,
    progress: Progress | None = None,
    *,
    clock: Clock = time.perf_counter,
) -> Schedule:
    """Plan the fleet with ``settings.algorithm``. Instances with an empty gene space
    (``problem.reasons``) get -1 and make the schedule infeasible, with their reasons. When
    NSGA-II finds no plan that gives every instance its deadline's CPU and
    ``settings.allowDegraded`` holds, the lowest-priority instances get less
    (``scheduling.degrade``; ``Schedule.degraded``). ``clock`` times NSGA-II's budget, one
    budget for the whole plan: the degraded search has what the first search and the
    degradation's packing search (stopped at ``EVOLUTION_SHARE``) left of it."""
    algo = SchedulerName(settings.algorithm)
    if algo is SchedulerName.NSGA2:
        t0 = clock()
        # a site proved short of CPU degrades at once: a search at full CPU cannot succeed
        short = settings.allow_degraded and short_of_cpu(problem)
        sched = None if short else nsga2(problem, settings, progress, clock=clock)
        if (sched is None or not sched.feasible) and settings.allow_degraded:
            budget = Budget(clock, t0, parse_millis(settings.time_budget_millis))
            degraded = degrade(
                problem,
                lambda p: nsga2(p, settings, progress, clock=clock, started=t0),
                stop=lambda: budget.over("degradation", EVOLUTION_SHARE),
            )
            if degraded is not None:
                return replace(degraded, duration_seconds=clock() - t0)
        if sched is None:  # degrading could not help: the search says what is infeasible
            sched = nsga2(problem, settings, progress, clock=clock, started=t0)
        return sched
    if algo is SchedulerName.K8S_DEFAULT:
        return k8s_default(problem, settings.seed)
    if algo is SchedulerName.ONBOARD:
        return onboard_plan(problem)
    if algo is SchedulerName.RANDOM:
        return random_plan(problem, settings.seed)
    t0 = time.perf_counter()
    w = exact_weights(problem, settings)
    res = solve_exact(problem, w)
    return finish(
        problem,
        "exact",
        res.placement,
        True,
        t0,
        f"MILP optimum {scalarised(problem, res.placement, w):.6g} of the weighted sum "
        f"{describe_weights(w)}",
    )


def every_choice(table: NDArray[np.int64], counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """Every combination of the genes' choices (gene ``g`` takes ``table[g, :counts[g]]``), the
    first gene slowest: the rows ``np.meshgrid(..., indexing="ij")`` would give, for any number
    of genes (numpy broadcasts at most 32 arrays, and a fleet whose instances each have one
    node left, as when a cluster is cut off, has more genes than that)."""
    total = int(np.prod(counts.astype(np.float64)))
    rest = np.arange(total, dtype=np.int64)
    out = np.empty((total, len(counts)), dtype=table.dtype)
    for g in range(len(counts) - 1, -1, -1):
        n = int(counts[g])
        out[:, g] = table[g, rest % n]
        rest //= n
    return out


def nsga2(
    problem: Problem,
    settings: SchedulerSettings,
    progress: Progress | None = None,
    *,
    paper: bool = False,
    local_search: bool | None = None,
    warm_start: bool | None = None,
    priced: bool = True,
    clock: Clock = time.perf_counter,
    started: float | None = None,
) -> Schedule:
    """NSGA-II over the gene spaces with the limits allocation.

    fogfleet's configuration: seeded sampling (current placement and greedy plans), the
    capacity repair on every new individual, uniform crossover, mutation of
    ``mutation_percent`` % of the offspring (1/G of their genes), duplicate elimination.
    ``paper=True`` is the stand-in for the paper's PyGAD setup: random sampling, no repair,
    single-point crossover, every gene mutated with p = mutation_percent %, constraints
    only as a penalty on the objectives. The evolution stops after ``generations``, once
    converged (``stall_generations``, ``convergence``; not the stand-in) or once its share of
    ``time_budget_millis`` has passed (``Schedule.generations`` tells how many ran); the
    levelling, the Pareto local search and the polish after it are bounded by work, so the
    same seed and the same number of generations give the same plan whatever the clock did
    (rerun with ``generations`` set to the count a budget-cut run reached to reproduce it),
    unless the budget cuts them too (``Schedule.budget_cut``; ``EVOLUTION_SHARE`` and the
    shares after it keep the whole search within the budget). ``clock`` is read for the budget and
    the durations (``time.perf_counter`` unless a test steers it). ``warm_start`` (default:
    from ``operators.WARM_START_GENES`` genes on) starts the population around the seed plans
    and runs ``convergence.WARM_GENERATIONS`` generations (unless ``stallGenerations`` is set).
    ``priced`` adds the robot bound's priced plan (``configurations.with_priced``) to what the
    local search starts from (``False``: the search before issue 46's priced plan, for
    ``fogfleet bench scale-plan``). ``started``: the ``clock()`` value the time budget counts
    from when the search is a later part of one plan (``plan``'s degraded search), else now.
    """
    t0 = clock()
    if local_search is None:
        local_search = not paper
    names = tuple(str(n) for n in settings.objectives)
    pp = PlacementProblem(problem, names, with_limits=True, penalty=1e3 if paper else None)
    if pp.n_var == 0:
        x = np.full(problem.n_instances, -1, dtype=np.int64)
        done = finish(problem, "nsga2", x, True, t0, "no instance has a node it may run on")
        return replace(done, duration_seconds=clock() - t0)
    budget = Budget(
        clock, t0 if started is None else started, parse_millis(settings.time_budget_millis)
    )
    log_space = float(np.log(pp.counts.astype(np.float64)).sum())  # log: no overflow
    exhaustive = not paper and log_space <= np.log(ENUMERATE_LIMIT)
    sampling = FleetSampling(heuristics=not paper, warm=warm_start)
    if exhaustive:
        # A search space this small is cheaper to enumerate than to evolve (pymoo's mating
        # loop would spin on duplicates), and the front is then exact.
        X = every_choice(pp.table, pp.counts)
        generations, n_eval, stop = settings.generations, len(X), Stop.EXHAUSTIVE
        local_search = False
    else:
        X, generations, n_eval, stop = _evolve(
            pp, settings, sampling, progress, clock, budget.ends(EVOLUTION_SHARE)
        )
    warm = not paper and not exhaustive and sampling.warm_for(pp)
    # objectives and constraints without any penalty, for an honest report
    # (the search's own problem when it has no penalty: one set of Fit tables, which take
    # seconds to build at 1000 robots)
    clean = pp if pp.penalty is None else PlacementProblem(problem, names, with_limits=True)
    out: dict[str, NDArray[np.float64]] = {}
    clean._evaluate(X, out)
    F, G = out["F"], out["G"]
    cv = np.maximum(G, 0.0).sum(axis=1)
    feasible = cv <= 1e-9
    n_local = 0
    bound = None
    if feasible.any() and local_search:
        idx = np.flatnonzero(feasible)
        X, F = X[idx], F[idx]
        searched = len(X)
        pairs = int(problem.allowed.sum())
        if priced and budget.fits(
            "priced plan", LOCAL_SEARCH_SHARE, PRICED_SECONDS_PER_PAIR * pairs
        ):
            X, F, bound = with_priced(
                clean,
                X,
                F,
                exact_weights(problem, settings),
                lambda: budget.over("priced plan", LOCAL_SEARCH_SHARE),
            )
        # a large fleet's priced plan is a level packing already: at 1000 robots levelling
        # after it took 3-4.5 s and changed neither the best S nor the chosen plan (seeds 1, 2
        # and 4); smaller fleets, and fleets with no priced plan, are levelled
        if not (warm and len(X) > searched):
            X, F = with_levelled(clean, X, F, lambda: budget.over("levelling", LOCAL_SEARCH_SHARE))
        X, F, n_local = pareto_local_search(
            clean, X, F, stop=lambda: budget.over("local search", LOCAL_SEARCH_SHARE)
        )
        cv = np.zeros(len(X))
        feasible = np.ones(len(X), dtype=bool)
    full = pp.full(X)
    F, cv, feasible = _spread_shared(clean, full, F, cv, feasible)
    X = full[:, pp.genes]
    if feasible.any():
        idx = np.flatnonzero(feasible)
        front = idx[non_dominated(F[idx])]
        k, reason = choose_plan(problem, full[front], F[front], names, settings)
        chosen = int(front[k])
        if exhaustive:
            reason += f" (exact front: all {len(X)} plans enumerated)"
        plan_x = full[chosen]
        if str(settings.choice.value) == "lexicographic" and not paper:
            plan_x, moved = polish(
                problem, plan_x, names, lambda: budget.over("polish", POLISH_SHARE)
            )
            if moved:
                reason += (
                    f"; then {moved} instance(s) moved to a preferred or cheaper node at no miss"
                )
    else:
        front = np.array([int(np.argmin(cv))], dtype=np.int64)
        chosen = int(front[0])
        plan_x = full[chosen]
        reason = f"no feasible plan found; least constraint violation {cv[chosen]:.4g}"
    note = spread_note(problem, plan_x)
    reason += f"; {note}" if note else ""
    sched = finish(problem, "nsga2", plan_x, True, t0, reason)
    if not feasible.any():
        extra = dict(sched.reasons)
        extra[-1] = "no plan satisfies the capacity and uplink constraints"
        sched = replace(sched, reasons=extra)
    if stop is Stop.BUDGET:
        budget.cut.insert(0, "evolution")
    why_stopped = {
        Stop.BUDGET: f" (time budget reached after {generations} generations; set generations: "
        f"{generations} to reproduce this plan)",
        Stop.STALLED: f" (converged after {generations} generations: the best plan had not "
        f"improved in the last {stall_window(settings.stall_generations, pp.n_var, warm)} "
        "generations)",
        Stop.WARM: f" (warm start: {generations} generations from the seed plans)",
    }.get(stop, "")
    if budget.cut[stop is Stop.BUDGET :]:  # a stage after the evolution was cut too
        why_stopped = (
            f" (time budget of {budget.seconds:g} s reached: it cut the "
            f"{', the '.join(budget.cut)} after {generations} generations; another run may "
            "give another plan)"
        )
    spent, planning = clock() - t0, clock() - budget.start
    if planning > OVER_BUDGET * budget.seconds:
        why_stopped += (
            f"; planning took {planning:.3g} s, over the time budget of {budget.seconds:g} s: "
            "the first population (the seed plans and their repair) and a step under way are "
            "never cut"
        )
    return replace(
        sched,
        choice_reason=sched.choice_reason + why_stopped,
        pareto_front=F[front],
        pareto_placements=full[front],
        objective_names=names,
        generations=generations,
        time_budget_reached=bool(budget.cut),
        budget_cut=tuple(budget.cut),
        robot_bound=bound,
        evaluations=n_eval + n_local,
        duration_seconds=spent,
    )


def _spread_shared(
    pp: PlacementProblem,
    full: NDArray[np.int64],
    F: NDArray[np.float64],
    cv: NDArray[np.float64],
    feasible: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The final candidates with every shared module spread where a second allowed node has
    room (``spread.spread_plans``; ``full`` in place), re-evaluated: the enumeration and the
    local search make plans the repair never saw, and the choice must pay for the spread."""
    moved = stacked(pp.fleet, full).any(axis=1)
    if not moved.any():
        return F, cv, feasible
    spread_plans(pp.fleet, full, pp.fit)
    out: dict[str, NDArray[np.float64]] = {}
    pp._evaluate(full[moved][:, pp.genes], out)
    F, cv, feasible = F.copy(), cv.copy(), feasible.copy()
    F[moved] = out["F"]
    cv[moved] = np.maximum(out["G"], 0.0).sum(axis=1)
    feasible[moved] = cv[moved] <= 1e-9
    return F, cv, feasible


def _evolve(
    pp: PlacementProblem,
    settings: SchedulerSettings,
    sampling: FleetSampling,
    progress: Progress | None,
    clock: Clock,
    budget_ends: float,
) -> tuple[NDArray[np.int64], int, int, Stop]:
    """Run NSGA-II; the final population's genes, generations run, evaluations and why it
    stopped. The budget is checked after each generation: once ``clock()`` passes
    ``budget_ends`` the evolution stops. fogfleet's configuration also stops early once
    converged (``convergence``); the paper's stand-in runs every generation."""
    paper = not sampling.heuristics  # the paper's stand-in samples at random
    warm = sampling.warm_for(pp)
    mut = settings.mutation_percent / 100.0
    crossover = GeneCrossover("single_point" if paper else "uniform")
    mutation = GeneMutation(prob=1.0, per_gene=mut) if paper else GeneMutation(prob=mut)
    repair = None if paper else CapacityRepair()
    algorithm = FleetNSGA2(
        pop_size=settings.population,
        sampling=sampling,
        crossover=crossover,
        mutation=mutation,
        repair=repair,
        eliminate_duplicates=GeneDuplicates(),
        survival=RankAndCrowdingSurvival(),
        selection=TournamentSelection(func_comp=binary_tournament),
        # the paper's stand-in keeps pymoo's own mating; fogfleet mates on gene arrays
        mating=None if paper else ArrayMating(crossover, mutation, repair),
        evaluator=ArrayEvaluator(),
    )
    algorithm.setup(
        pp, termination=("n_gen", settings.generations), seed=settings.seed, verbose=False
    )
    watch = StallWatch(0 if paper else stall_window(settings.stall_generations, pp.n_var, warm))
    generations, stop = 0, Stop.GENERATIONS
    while algorithm.has_next():
        algorithm.next()
        generations = int(algorithm.n_gen) - 1 if algorithm.n_gen is not None else generations + 1
        if progress is not None:
            progress(generations, settings.generations)
        if watch.window and generations < settings.generations:
            pop = algorithm.pop
            F = np.array([ind.F for ind in pop], dtype=np.float64)
            if watch.update(F, np.array([ind.CV[0] for ind in pop], dtype=np.float64)):
                stop = Stop.STALLED
                break
        if warm and generations >= WARM_GENERATIONS and settings.stall_generations is None:
            stop = Stop.WARM
            break
        if clock() > budget_ends and generations < settings.generations:
            stop = Stop.BUDGET
            break
    X = np.asarray(algorithm.pop.get("X")).astype(np.int64)
    return X, generations, int(algorithm.evaluator.n_eval), stop


def choose_plan(
    problem: Problem,
    plans: I64,
    F: NDArray[np.float64],
    names: tuple[str, ...],
    settings: SchedulerSettings,
) -> tuple[int, str]:
    """``choice.choose`` on the front. A lexicographic choice breaks ties on its leading miss
    objectives first by the soft rules of ``preference.tie_breakers`` (preferred tiers, then
    cost), then by the other objectives."""
    rule = str(settings.choice.value)
    lead = 0
    while lead < len(names) and names[lead] in MISS_OBJECTIVES:
        lead += 1
    extra = tie_breakers(problem, plans, names)
    if rule != "lexicographic" or lead == 0 or not extra:
        return choose(F, names, rule, weights_of(settings))
    F2 = np.column_stack([F[:, :lead], *extra.values(), F[:, lead:]])
    return choose(F2, (*names[:lead], *extra, *names[lead:]), rule, weights_of(settings))
