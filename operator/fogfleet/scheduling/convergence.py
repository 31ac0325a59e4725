"""When NSGA-II has converged: the stall rule that ends the evolution before ``generations``.

The plan fogfleet deploys is chosen lexicographically from the front (objectives in the
order of ``spec.scheduler.objectives``, multi-robot-edge-cloud-scheduling III-C), so the
evolution is watched through that lens: after each generation, the population's
lexicographically best feasible objective vector. Once it has not improved for
``window`` generations, the evolution stops and the Pareto local search takes over.

Measured on the warehouse fleet (seeds 1-12, 40 genes): that vector last improves between
generations 1 and 51, and the plan after the local search is as close to the MILP optimum
after 30 generations as after 100 (mean gap 0.27 % either way), so most of the default 100
generations were spent on a converged population. A 1000-gene fleet (125 robots x 8 on 50
edges) keeps improving past generation 100 with pauses of up to 10 generations in between:
stopping it at the first such pause cost 7 % more on-board use. Hence the default window
grows with the genes: ``max(10, genes / 10)``.

The rule reads only objective values, never the clock, so the same seed stops at the same
generation and gives the same plan on any machine.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["MIN_WINDOW", "WARM_GENERATIONS", "WARM_WINDOW", "StallWatch", "stall_window"]

MIN_WINDOW = 10  # generations
WARM_WINDOW = 1  # generation, after a warm start
# Generations a warm start runs at most (the first is the seeded population) unless the fleet
# sets stallGenerations. At 1000 robots x 8 modules (seed 1) the best S on the final front was
# 1.26802 after 1, 2 and 6 generations alike: the levelling and the local search after NSGA-II
# decide it, and each generation's repair of 100 children cost ~1.5 s.
WARM_GENERATIONS = 2
GENES_PER_GENERATION = 10  # the default window grows by one generation per this many genes
RELATIVE_TOLERANCE = 1e-9  # float noise, not an improvement


def stall_window(setting: int | None, n_genes: int, warm: bool = False) -> int:
    """Generations without improvement that end the evolution (0: never). ``setting`` is
    ``spec.scheduler.stallGenerations``; unset, ``max(10, genes / 10)``, or 10 when the
    population was warm-started (``operators.warm_population``): it then starts next to the
    constructive plans, and what is left to gain is the peak levelling and the Pareto local
    search after it, not more generations (1000 robots x 8 modules: see ``WARM_WINDOW``)."""
    if setting is not None:
        return setting
    if warm:
        return WARM_WINDOW
    return max(MIN_WINDOW, n_genes // GENES_PER_GENERATION)


def lexicographic_best(F: NDArray[np.float64]) -> NDArray[np.float64]:
    """The row of ``F`` that is smallest in the first objective, ties broken by the next."""
    best: NDArray[np.float64] = F[int(np.lexsort(F.T[::-1])[0])]
    return best


def improves(candidate: NDArray[np.float64], best: NDArray[np.float64]) -> bool:
    """Whether ``candidate`` is lexicographically better than ``best`` by more than float
    noise in the first objective where they differ."""
    for c, b in zip(candidate, best, strict=True):
        slack = RELATIVE_TOLERANCE * max(abs(float(b)), 1.0)
        if c < b - slack:
            return True
        if c > b + slack:
            return False
    return False


class StallWatch:
    """Feed it each generation's objectives and constraint violations; ``stalled`` says when
    the best feasible plan has not improved for ``window`` generations (never while no plan
    is feasible, never with a window of 0)."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.best: NDArray[np.float64] | None = None
        self.generation = 0
        self.improved_at = 0

    def update(self, F: NDArray[np.float64], cv: NDArray[np.float64]) -> bool:
        """Record one generation; True when the evolution should stop."""
        self.generation += 1
        feasible = cv <= 0.0
        if not feasible.any():
            self.improved_at = self.generation
            return False
        candidate = lexicographic_best(F[feasible])
        if self.best is None or improves(candidate, self.best):
            self.best = candidate
            self.improved_at = self.generation
        return self.stalled

    @property
    def stalled(self) -> bool:
        return self.window > 0 and self.generation - self.improved_at >= self.window
