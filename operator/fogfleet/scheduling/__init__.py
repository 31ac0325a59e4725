"""The pure scheduling core: objectives (F1-F4 and extensions), the pymoo problem and
operators, NSGA-II and baseline planners, Pareto choice and an exact MILP
(the benchmarks are in ``fogfleet.bench``).

Entry point: ``plan(problem, settings, progress) -> Schedule``.
"""

from .choice import choose, non_dominated
from .exact import scalarised, solve_exact
from .objectives import OBJECTIVES, constraints, evaluate
from .schedule import Schedule
from .solver import plan

__all__ = [
    "OBJECTIVES",
    "Schedule",
    "choose",
    "constraints",
    "evaluate",
    "non_dominated",
    "plan",
    "scalarised",
    "solve_exact",
]
