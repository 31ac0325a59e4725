"""A profile row (one CPU limit's execution time, mean and std) and the correction learnt for
a module's declared rows from what ran.

``pairs`` builds rows and applies corrections, ``observed`` learns them: both import this
module, neither imports the other.

**Noise where it was never measured** (issue 49: a loop that never moves on noise). The cycle's
noise (``domain.observed``) is what a cycle of the module costs besides its work: wake-ups, the
middleware, the host's other processes. It is learnt on the hardware types the module ran on;
on a type it never ran on (or ran too few cycles on to fit it, ``spec.drift.minCycles``) the
noise is not known. Taking it as zero there, as the prior does, makes every node the module
never ran on look quieter than the one it runs on, by exactly the noise just learnt: the
re-plan then moves it for a gain that is only the absence of a measurement, and it misses at
least as much where it lands (issue 49: the real-node benchmark's loop moved a pose estimator
onto the small edge, and perception missed 1.0-3.0 % in those runs against 0.05-0.2 %
simulated). So
``carry_noise`` gives such a type the largest noise the module has shown on another type: the
pessimistic end of what is known of the destination. A move then gains only from what differs
between the nodes (their work, CPU, transfers, measured factors), never from the noise alone;
a type the module ran on long enough keeps its own noise, zero included, so a module may
return to where it ran quietly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

__all__ = ["Learnt", "ProfileRow", "carry_noise"]


@dataclass(frozen=True)
class ProfileRow:
    """One row of a module's profile on a node: cores, execution time mean and std (s)."""

    cpu: float
    mean: float
    std: float


@dataclass(frozen=True)
class Learnt:
    """A module's declared rows on one hardware type as what ran corrects them."""

    factor: float = 1.0
    noise: float = 0.0  # seconds: std of what a cycle takes besides its work and transfer
    noise_cycles: float = 0.0
    """Cycles the noise was fitted from on this type; 0 with no noise: not known here (too few
    cycles), so ``carry_noise`` may give it the noise the module shows elsewhere."""

    @property
    def noise_known(self) -> bool:
        """Whether the noise on this type was measured (a fitted noise, or enough cycles)."""
        return self.noise > 0 or self.noise_cycles > 0

    def row(self, r: ProfileRow) -> ProfileRow:
        """The declared row ``r`` corrected: mean and std times the factor, the noise added
        to the std (independent normal terms)."""
        return ProfileRow(r.cpu, r.mean * self.factor, math.hypot(r.std * self.factor, self.noise))


def carry_noise(
    corrections: Mapping[tuple[str, str], Learnt], hardware_types: Iterable[str]
) -> dict[tuple[str, str], Learnt]:
    """``corrections`` ((module, hardware type) -> Learnt) with, for every module that has a
    noise known on some type, that noise (the largest, if several) on each of
    ``hardware_types`` where its own is not known (module docstring): a type without a
    correction gets the declared rows plus that noise, one with a factor alone keeps the
    factor."""
    out = dict(corrections)
    worst: dict[str, float] = {}
    for (module, _), got in corrections.items():
        if got.noise_known:
            worst[module] = max(worst.get(module, 0.0), got.noise)
    types = sorted(set(hardware_types))
    for module, noise in sorted(worst.items()):
        if noise <= 0:
            continue
        for hw in types:
            got = out.get((module, hw), Learnt())
            if not got.noise_known:
                out[(module, hw)] = Learnt(got.factor, noise)
    return out
