"""A profile row (one CPU limit's execution time, mean and std) and the correction learnt for
a module's declared rows from what ran.

``pairs`` builds rows and applies corrections, ``observed`` learns them: both import this
module, neither imports the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Learnt", "ProfileRow"]


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

    def row(self, r: ProfileRow) -> ProfileRow:
        """The declared row ``r`` corrected: mean and std times the factor, the noise added
        to the std (independent normal terms)."""
        return ProfileRow(r.cpu, r.mean * self.factor, math.hypot(r.std * self.factor, self.noise))
