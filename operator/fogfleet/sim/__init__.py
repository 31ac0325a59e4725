"""Discrete-event fleet simulator (pure: numpy only): runs a plan and measures missed cycles.

``simulate`` runs one plan for one seed; ``compare`` runs several plans over several seeds.
The execution model is the team's shared one (see ``simulator``, ``engine``, ``episodes``);
``model.ExecutionModel`` adds what a real node adds to it (the cycle's cost, the kernel's
spreading of a shortage), fitted on a benchmark's pilot.
"""

from .compare import PlanSummary, compare
from .model import DECLARED, ExecutionModel
from .result import SimResult
from .simulator import simulate

__all__ = ["DECLARED", "ExecutionModel", "PlanSummary", "SimResult", "compare", "simulate"]
