"""Discrete-event fleet simulator (pure: numpy only): runs a plan and measures missed cycles.

``simulate`` runs one plan for one seed; ``compare`` runs several plans over several seeds.
The execution model is the team's shared one (see ``simulator``, ``engine``, ``episodes``).
"""

from .compare import PlanSummary, compare
from .result import SimResult
from .simulator import simulate

__all__ = ["PlanSummary", "SimResult", "compare", "simulate"]
